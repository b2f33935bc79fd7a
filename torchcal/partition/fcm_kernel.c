/* One fused iteration of fuzzy c-means with m = 2 over all points (fcm_pass_m2), and the
 * first centers from starting memberships (fcm_start_m2), for torchcal.partition.fcm
 * (docs/paper.md eqs. 26-28). Compiled on the user's machine at first use and loaded with
 * ctypes by torchcal/partition/_native.py; the eager torch kernel of fcm.py is the reference
 * and the fallback.
 *
 * Points xt (d, N) float64, row k at xt + k * N (features of point j: xt[k * N + j]);
 * centers V (c, d) row-major; memberships (c, N) row-major. Eight points at a time (GCC/Clang
 * vector extensions: one AVX-512 register, two AVX2 ones):
 *   d2_i  = sum_k (x_k - v_ik)^2                       squared distances, direct differences
 *   q_i   = prod_{l != i} d2_l,  S = sum_i q_i          eq. 28 for m = 2 as a product form:
 *   u_i   = q_i / S                                      u_i = (1/d2_i) / sum_l (1/d2_l)
 * one division per point (not c + 1), and a point on one center gets u = 1 there exactly.
 * J adds prod_i d2_i / S (= sum_i u_i^2 d2_i, eq. 26). The check adds S * (1 / S): NaN
 * where S is 0 or inf (a point on two centers, or products that under- or overflow), and
 * then the caller redoes the iteration with the careful eager path.
 * Sums: per lane, over blocks of BLOCK points, then the block sums added to the totals.
 */
#include <string.h>

typedef double v8 __attribute__((vector_size(64)));
typedef double v8u __attribute__((vector_size(64), aligned(8)));

enum { DMAX = 8, CMAX = 16, BLOCK = 4096 };

/* Memberships of eight points x[0..d-1] from centers V (c, d): u[0..c-1]; *chk = S * (1/S)
 * (NaN or inf where S is 0 or inf), *J = prod_i d2_i / S (their part of eq. 26). */
static inline __attribute__((always_inline)) void
memberships8(const v8 *x, const double *restrict V, int d, int c, v8 *u, v8 *chk, v8 *J)
{
    v8 w[CMAX], pre[CMAX];
    for (int i = 0; i < c; i++) {
        v8 t = x[0] - V[i * d];
        v8 s = t * t;
        for (int k = 1; k < d; k++) {
            t = x[k] - V[i * d + k];
            s += t * t;
        }
        w[i] = s;
    }
    v8 p = (v8){0} + 1.0;
    for (int i = 0; i < c; i++) {
        pre[i] = p;
        p *= w[i];
    }
    v8 suf = (v8){0} + 1.0, S = {0};
    for (int i = c - 1; i >= 0; i--) {
        u[i] = pre[i] * suf;
        suf *= w[i];
        S += u[i];
    }
    v8 inv = 1.0 / S;
    for (int i = 0; i < c; i++)
        u[i] *= inv;
    *chk = S * inv;
    *J = p * inv;
}

/* p[0..n-1] and p[n-1] repeated: eight values. */
static inline v8 load_tail(const double *p, int n)
{
    double t[8];
    for (int l = 0; l < 8; l++)
        t[l] = p[l < n ? l : n - 1];
    v8 v;
    memcpy(&v, t, sizeof v);
    return v;
}

/* Eight points, the j-th to the (j + n - 1)-th of N (n < 8 only at the ragged end, where
 * `tail` is set: the last point is repeated and its copies masked out of the sums), added
 * into the block's sums blk ((d+1) c), *Jb, *Db and *Cb (see pass_body). */
static inline __attribute__((always_inline)) void
group8(const double *restrict xt, long N, long j, int n, int tail, int d, int c,
       const double *restrict V, const double *restrict Vp, const double *restrict U0,
       double *restrict U, v8 *blk, v8 *Jb, v8 *Db, v8 *Cb)
{
    v8 x[DMAX], u[CMAX], chk, J, mask = (v8){0} + 1.0;
    if (!tail) {
        for (int k = 0; k < d; k++)
            x[k] = *(const v8u *)(xt + k * N + j);
    } else {
        for (int k = 0; k < d; k++)
            x[k] = load_tail(xt + k * N + j, n);
        for (int l = n; l < 8; l++)
            mask[l] = 0.0;
    }
    memberships8(x, V, d, c, u, &chk, &J);
    *Cb += chk;
    *Jb += tail ? J * mask : J;
    if (Vp != NULL || U0 != NULL) {
        v8 up[CMAX], dd = {0};
        if (Vp != NULL) {
            v8 chp, Jp;
            memberships8(x, Vp, d, c, up, &chp, &Jp);
            *Cb += chp;
        } else {
            v8 s = {0};
            for (int i = 0; i < c; i++) {
                if (!tail)
                    up[i] = *(const v8u *)(U0 + i * N + j);
                else
                    up[i] = load_tail(U0 + i * N + j, n);
                s += up[i];
            }
            v8 is = 1.0 / s;
            for (int i = 0; i < c; i++)
                up[i] *= is;
        }
        for (int i = 0; i < c; i++) {
            v8 t = u[i] - up[i];
            dd += t * t;
        }
        *Db += tail ? dd * mask : dd;
    }
    if (U != NULL) {
        for (int i = 0; i < c; i++) {
            if (!tail)
                *(v8u *)(U + i * N + j) = u[i];
            else
                for (int l = 0; l < n; l++)
                    U[i * N + j + l] = u[i][l];
        }
        return;
    }
    for (int i = 0; i < c; i++) {
        v8 u2 = u[i] * u[i];
        if (tail)
            u2 *= mask;
        for (int k = 0; k < d; k++)
            blk[k * c + i] += u2 * x[k];
        blk[d * c + i] += u2;
    }
}

/* The pass. V (c, d) the centers; Vp (c, d) the previous ones or NULL; U0 (c, N) the starting
 * memberships (columns not normalised) or NULL; when Vp or U0 is given, ||U(V) - U(prev)||^2
 * is summed. U: NULL, or (c, N) that receives U(V), and then no sums for eq. 27 are made.
 * out: [(d+1) c sums for eq. 27: out[k c + i] = sum_j u_ij^2 x_kj (k < d),
 * out[d c + i] = sum_j u_ij^2; J; ||dU||^2; check], overwritten. */
static inline __attribute__((always_inline)) void
pass_body(const double *restrict xt, long N, int d, int c, const double *restrict V,
          const double *restrict Vp, const double *restrict U0, double *restrict U,
          double *restrict out)
{
    const int na = (d + 1) * c;
    v8 tot[(DMAX + 1) * CMAX], blk[(DMAX + 1) * CMAX];
    v8 Jt = {0}, Dt = {0}, Ct = {0};
    for (int q = 0; q < na; q++)
        tot[q] = (v8){0};
    for (long b = 0; b < N; b += BLOCK) {
        long e = b + BLOCK < N ? b + BLOCK : N, j;
        v8 Jb = {0}, Db = {0}, Cb = {0};
        for (int q = 0; q < na; q++)
            blk[q] = (v8){0};
        for (j = b; j + 8 <= e; j += 8)
            group8(xt, N, j, 8, 0, d, c, V, Vp, U0, U, blk, &Jb, &Db, &Cb);
        if (j < e)
            group8(xt, N, j, (int)(e - j), 1, d, c, V, Vp, U0, U, blk, &Jb, &Db, &Cb);
        for (int q = 0; q < na; q++)
            tot[q] += blk[q];
        Jt += Jb;
        Dt += Db;
        Ct += Cb;
    }
    for (int q = 0; q < na; q++) {
        double s = 0.0;
        for (int l = 0; l < 8; l++)
            s += tot[q][l];
        out[q] = s;
    }
    double sj = 0.0, sd = 0.0, sc = 0.0;
    for (int l = 0; l < 8; l++) {
        sj += Jt[l];
        sd += Dt[l];
        sc += Ct[l];
    }
    out[na] = sj;
    out[na + 1] = sd;
    out[na + 2] = sc;
}

/* Specialised for the common small d and c (loops unrolled, sums kept in registers), and one
 * general version for d <= DMAX, c <= CMAX. */
#define SPEC(D, C)                                                                              \
    static void pass_##D##_##C(const double *xt, long N, const double *V, const double *Vp,   \
                               const double *U0, double *U, double *out)                       \
    {                                                                                           \
        pass_body(xt, N, D, C, V, Vp, U0, U, out);                                              \
    }
#define SPEC_D(D) SPEC(D, 2) SPEC(D, 3) SPEC(D, 4) SPEC(D, 5) SPEC(D, 6)
SPEC_D(1)
SPEC_D(2)
SPEC_D(3)

typedef void (*pass_fn)(const double *, long, const double *, const double *, const double *,
                        double *, double *);
#define ROW(D) {pass_##D##_2, pass_##D##_3, pass_##D##_4, pass_##D##_5, pass_##D##_6}
static const pass_fn SPECS[3][5] = {ROW(1), ROW(2), ROW(3)};

static void pass_any(const double *xt, long N, int d, int c, const double *V, const double *Vp,
                     const double *U0, double *U, double *out)
{
    pass_body(xt, N, d, c, V, Vp, U0, U, out);
}

/* Entry point: returns 0, or -1 when d or c is beyond DMAX or CMAX (nothing done). */
int fcm_pass_m2(const double *xt, long N, int d, int c, const double *V, const double *Vp,
                const double *U0, double *U, double *out)
{
    if (d < 1 || d > DMAX || c < 2 || c > CMAX)
        return -1;
    if (d <= 3 && c <= 6)
        SPECS[d - 1][c - 2](xt, N, V, Vp, U0, U, out);
    else
        pass_any(xt, N, d, c, V, Vp, U0, U, out);
    return 0;
}

/* The first centers (eq. 27, m = 2) from starting memberships U0 (c, N) (columns not
 * normalised): out[k c + i] = sum_j u_ij^2 x_kj (k < d), out[d c + i] = sum_j u_ij^2 with
 * u_ij = U0_ij / sum_l U0_lj, summed as in pass_body; out[(d+1) c] = the number of values of
 * U0 that are negative, NaN or inf, out[(d+1) c + 1] the number of columns whose sum is not
 * > 0 (the sums are then meaningless). Returns 0, or -1 when d or c is beyond DMAX or CMAX. */
int fcm_start_m2(const double *restrict xt, long N, int d, int c, const double *restrict U0,
                 double *restrict out)
{
    if (d < 1 || d > DMAX || c < 2 || c > CMAX)
        return -1;
    const int na = (d + 1) * c;
    v8 tot[(DMAX + 1) * CMAX], blk[(DMAX + 1) * CMAX];
    v8 bad = {0}, zero = {0};
    for (int q = 0; q < na; q++)
        tot[q] = (v8){0};
    for (long b = 0; b < N; b += BLOCK) {
        long e = b + BLOCK < N ? b + BLOCK : N;
        for (int q = 0; q < na; q++)
            blk[q] = (v8){0};
        for (long j = b; j < e; j += 8) {
            int n = e - j < 8 ? (int)(e - j) : 8;
            v8 x[DMAX], u[CMAX], s = {0}, mask = (v8){0} + 1.0;
            for (int l = n; l < 8; l++)
                mask[l] = 0.0;
            for (int k = 0; k < d; k++)
                x[k] = n == 8 ? *(const v8u *)(xt + k * N + j) : load_tail(xt + k * N + j, n);
            for (int i = 0; i < c; i++) {
                u[i] = n == 8 ? *(const v8u *)(U0 + i * N + j) : load_tail(U0 + i * N + j, n);
                /* 1 where the value is not in [0, inf): negative, NaN or inf */
                bad += mask * (1.0 + __builtin_convertvector((u[i] >= 0.0) & (u[i] < __builtin_inf()), v8));
                s += u[i];
            }
            zero += mask * (1.0 + __builtin_convertvector(s > 0.0, v8));
            v8 is = 1.0 / s;
            for (int i = 0; i < c; i++) {
                v8 u2 = u[i] * is;
                u2 = u2 * u2 * mask;
                for (int k = 0; k < d; k++)
                    blk[k * c + i] += u2 * x[k];
                blk[d * c + i] += u2;
            }
        }
        for (int q = 0; q < na; q++)
            tot[q] += blk[q];
    }
    for (int q = 0; q < na; q++) {
        double t = 0.0;
        for (int l = 0; l < 8; l++)
            t += tot[q][l];
        out[q] = t;
    }
    double nb = 0.0, nz = 0.0;
    for (int l = 0; l < 8; l++) {
        nb += bad[l];
        nz += zero[l];
    }
    out[na] = nb;
    out[na + 1] = nz;
    return 0;
}
