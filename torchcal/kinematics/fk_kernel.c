/* Perturbed forward kinematics, one pass per (pose, parameter set) pair with everything in
 * registers, for torchcal.kinematics.fk_native (which builds and loads it with ctypes through
 * torchcal/native.py). The eager torch kernel `torchcal.kinematics.mdh.positions_into` is the
 * reference: this is its recursion, lane by lane,
 *
 *     u = R_(n-1) tool + t_(n-1)
 *     u = R_i Rz(q_(i+1)) u + t_i          for i = n-2 .. 0
 *     p = R_base Rz(q_1) u + b              (p = Rz(q_1) u without a base frame)
 *
 * with R_i = Rz(off_i + dtheta_i) Rx(alpha_i) Ry(beta_i), t_i = Rz(off_i + dtheta_i) [a_i, 0, d_i]
 * (12 numbers per link and parameter set, made by the caller), cos and sin of q per joint and
 * pose (made by the caller), and a prismatic joint's travel added to the z of u. A row of
 * R z + t is t + three products (three fused multiply-adds; the eager kernel adds t last), so
 * the results differ from it in the last bits (1e-12 mm at metres).
 *
 * The start, u_(n-1) without a prismatic joint's travel, is per set only, so the caller makes
 * it once per set, as the eager kernel does.
 *
 * Layouts (T = double or float; `idx` a pose or a set):
 *   pose (n, 3, Q): [cos q, sin q, travel] of joint i at pose[(3 i + k) Q + idx];
 *   link (n + 1, 12, S): [R00 R01 R02 R10 R11 R12 R20 R21 R22 t0 t1 t2] of link i at
 *     link[(12 i + k) S + idx] for i < n - 1 (link n - 1's are not read), then at i = n the
 *     start u_(n-1) = R_(n-1) tool + t_(n-1) in k = 0, 1, 2 (the rest unused);
 *   lin (n) int: 1 at a prismatic joint; base (12) [R_base row-major, b] or NULL.
 * Q and S are row lengths: each row ends in 16 copies of its last value (the caller pads),
 * so that a vector that starts at a used index never reads past its row.
 *
 * fk_positions_*: the pairs k = a B + b of a grid (A, B), k in [k0, k1), written to
 * out[3 k .. 3 k + 2]; pose index a qa + b qv, set index a sa + b sv (qv, sv: 0 or 1).
 * The inner index b runs over L pairs at once (8 doubles or 16 floats; GCC/Clang vector
 * extensions: one 512-bit register, two 256-bit ones), from the poses (qv = 1), the sets
 * (sv = 1) or both; a ragged end (fewer than L pairs) computes L lanes and stores its
 * pairs. Returns 0, or -1 (nothing done) for n < 1.
 *
 * error_extremes_*: for points a in [a0, a1) (pose index a, L points a vector) and the M sets
 * (one at a time, broadcast), the error e = p - nominal in the joint-1 frame (no base), turned
 * by `rot` (9, row-major) when given; nominal (3, Q) laid out and padded like a row of pose;
 * res[8 a ..] = min e (3), max e (3), min |e|^2, max |e|^2 (NaN-free inputs assumed), the
 * running extremes of each point in its lane (no reduction across lanes).
 *
 * The file includes itself once per type (see the end).
 */
#ifndef FK_TYPE

#include <string.h>

typedef double vd __attribute__((vector_size(64)));
typedef float vf __attribute__((vector_size(64)));
typedef long long md __attribute__((vector_size(64))); /* their comparison masks */
typedef int mf __attribute__((vector_size(64)));

#define FK_REP8(x) x, x, x, x, x, x, x, x /* a vector's initialiser: x in every lane */
#define FK_REP16(x) FK_REP8(x), FK_REP8(x)

#define FK_TYPE double
#define FK_VEC vd
#define FK_MASK md
#define FK_LANES 8
#define FK_REP FK_REP8
#define FK_NAME(x) x##_f64
#include __FILE__
#undef FK_TYPE
#undef FK_VEC
#undef FK_MASK
#undef FK_REP
#undef FK_LANES
#undef FK_NAME

#define FK_TYPE float
#define FK_VEC vf
#define FK_MASK mf
#define FK_LANES 16
#define FK_REP FK_REP16
#define FK_NAME(x) x##_f32
#include __FILE__

#else /* the kernels for one type */

typedef FK_TYPE FK_NAME(real);
typedef FK_VEC FK_NAME(vec);
typedef FK_MASK FK_NAME(mask);
#define T FK_NAME(real)
#define V FK_NAME(vec)
#define MK FK_NAME(mask)
#define L FK_LANES

/* L values at p (vec = 1) or *p in every lane (vec = 0). */
static inline __attribute__((always_inline)) V FK_NAME(get)(const T *p, int vec)
{
    V v;
    if (vec) {
        memcpy(&v, p, sizeof v);
        return v;
    }
    T x = *p; /* a broadcast ((V){0} + x would add 0 first: not a no-op, -0 + 0 = +0) */
    return (V){FK_REP(x)};
}

/* Lane by lane the smaller (less = 1) or the larger of x and y. */
static inline V FK_NAME(pick)(V x, V y, int less)
{
    MK k = less ? x < y : x > y;
    return (V)(((MK)x & k) | ((MK)y & ~k));
}

/* The positions of L pairs: pose, link offset to the group's first pose and set; rows Q and
 * S apart. Inlined where qv and sv are constants (the common grids) and in `grid_any`. */
static inline __attribute__((always_inline)) void
FK_NAME(chain)(const T *pose, long Q, int qv, const T *link, long S, int sv, int n, const int *lin,
               const T *base, V *px, V *py, V *pz)
{
#define LK(k) FK_NAME(get)(Li + (long)(k) * S, sv)
#define PS(j, k) FK_NAME(get)(pose + ((long)(j) * 3 + (k)) * Q, qv)
    int i = n - 1;
    const T *Li = link + (long)n * 12 * S; /* the start */
    V u0 = LK(0), u1 = LK(1), u2 = LK(2);
    if (lin[i])
        u2 += PS(i, 2);
    for (i = n - 2; i >= 0; i--) {
        V c = PS(i + 1, 0), s = PS(i + 1, 1);
        V z0 = c * u0 - s * u1, z1 = s * u0 + c * u1; /* Rz(q_(i+1)) u */
        Li = link + (long)i * 12 * S;
        V n0 = LK(9) + LK(2) * u2 + LK(0) * z0 + LK(1) * z1; /* three fused multiply-adds a row */
        V n1 = LK(10) + LK(5) * u2 + LK(3) * z0 + LK(4) * z1;
        V n2 = LK(11) + LK(8) * u2 + LK(6) * z0 + LK(7) * z1;
        if (lin[i])
            n2 += PS(i, 2);
        u0 = n0, u1 = n1, u2 = n2;
    }
    V c = PS(0, 0), s = PS(0, 1);
    V z0 = c * u0 - s * u1, z1 = s * u0 + c * u1;
    if (!base) {
        *px = z0, *py = z1, *pz = u2;
        return;
    }
    *px = base[9] + base[2] * u2 + base[0] * z0 + base[1] * z1;
    *py = base[10] + base[5] * u2 + base[3] * z0 + base[4] * z1;
    *pz = base[11] + base[8] * u2 + base[6] * z0 + base[7] * z1;
#undef LK
#undef PS
}

/* x, y, z of m pairs stored interleaved at o: o[3 l + c] (lane by lane: as fast as a copy
 * through the stack, faster than shuffles into three full vectors, measured). */
static inline __attribute__((always_inline)) void FK_NAME(store)(T *restrict o, V x, V y, V z, int m)
{
    for (int l = 0; l < m; l++) {
        o[3 * l] = x[l];
        o[3 * l + 1] = y[l];
        o[3 * l + 2] = z[l];
    }
}

/* The pairs [k0, k1) of the grid (see the top); `chain` inlined with qv and sv as given
 * (constants in the common grids). */
static inline __attribute__((always_inline)) void
FK_NAME(grid)(const T *pose, long Q, long qa, int qv, const T *link, long S, long sa, int sv, int n,
              const int *lin, const T *base, long B, long k0, long k1, T *restrict out)
{
    long k = k0;
    while (k < k1) {
        long a = k / B, b = k - a * B;
        long end = B < b + (k1 - k) ? B : b + (k1 - k);
        for (; b < end; b += L) { /* a ragged end reads past it (the padding) and stores m pairs */
            V x, y, z;
            FK_NAME(chain)(pose + a * qa + b * qv, Q, qv, link + a * sa + b * sv, S, sv, n, lin, base,
                           &x, &y, &z);
            FK_NAME(store)(out + (a * B + b) * 3, x, y, z, end - b < L ? (int)(end - b) : L);
        }
        k = a * B + end;
    }
}

/* `grid` with qv and sv read at run time (both 1: poses and sets element by element; both 0). */
static __attribute__((noinline)) void
FK_NAME(grid_any)(const T *pose, long Q, long qa, int qv, const T *link, long S, long sa, int sv, int n,
                  const int *lin, const T *base, long B, long k0, long k1, T *restrict out)
{
    FK_NAME(grid)(pose, Q, qa, qv, link, S, sa, sv, n, lin, base, B, k0, k1, out);
}

int FK_NAME(fk_positions)(const T *pose, long Q, long qa, int qv, const T *link, long S, long sa, int sv, int n,
                          const int *lin, const T *base, long B, long k0, long k1, T *out)
{
    if (n < 1)
        return -1;
    if (qv && !sv) /* poses inner: sets x poses */
        FK_NAME(grid)(pose, Q, qa, 1, link, S, sa, 0, n, lin, base, B, k0, k1, out);
    else if (sv && !qv) /* sets inner: poses x sets */
        FK_NAME(grid)(pose, Q, qa, 0, link, S, sa, 1, n, lin, base, B, k0, k1, out);
    else
        FK_NAME(grid_any)(pose, Q, qa, qv, link, S, sa, sv, n, lin, base, B, k0, k1, out);
    return 0;
}

int FK_NAME(error_extremes)(const T *pose, long Q, const T *link, long S, long M, int n, const int *lin,
                            const T *nominal, const T *rot, long a0, long a1, T *res)
{
    if (n < 1)
        return -1;
    for (long a = a0; a < a1; a += L) { /* L points at once, a ragged end reading the padding */
        V nom[3], lo[3], hi[3], dlo, dhi;
        for (int c = 0; c < 3; c++)
            nom[c] = FK_NAME(get)(nominal + c * Q + a, 1);
        for (long b = 0; b < M; b++) {
            V e[3];
            FK_NAME(chain)(pose + a, Q, 1, link + b, S, 0, n, lin, 0, &e[0], &e[1], &e[2]);
            e[0] -= nom[0], e[1] -= nom[1], e[2] -= nom[2];
            if (rot) {
                V r0 = rot[0] * e[0] + rot[1] * e[1] + rot[2] * e[2];
                V r1 = rot[3] * e[0] + rot[4] * e[1] + rot[5] * e[2];
                V r2 = rot[6] * e[0] + rot[7] * e[1] + rot[8] * e[2];
                e[0] = r0, e[1] = r1, e[2] = r2;
            }
            V d2 = e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
            if (b == 0) {
                for (int c = 0; c < 3; c++)
                    lo[c] = hi[c] = e[c];
                dlo = dhi = d2;
                continue;
            }
            for (int c = 0; c < 3; c++) {
                lo[c] = FK_NAME(pick)(e[c], lo[c], 1);
                hi[c] = FK_NAME(pick)(e[c], hi[c], 0);
            }
            dlo = FK_NAME(pick)(d2, dlo, 1);
            dhi = FK_NAME(pick)(d2, dhi, 0);
        }
        int m = a1 - a < L ? (int)(a1 - a) : L;
        for (int l = 0; l < m; l++) {
            T *r = res + 8 * (a + l);
            for (int c = 0; c < 3; c++) {
                r[c] = lo[c][l];
                r[3 + c] = hi[c][l];
            }
            r[6] = dlo[l], r[7] = dhi[l];
        }
    }
    return 0;
}

#undef T
#undef V
#undef MK
#undef L
#endif
