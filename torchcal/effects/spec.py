"""Effect specs: the vocabulary of physical effects and the ``NAME[:J,...]`` parser.

docs/design.md, "Physical effects": one vocabulary for models, simulation, diagnosis and
reports. On the command line an effect is named ``NAME`` or ``NAME:J[,J...]`` with
1-based joint numbers, e.g. ``joint_compliance:2,3``, ``gear_periodic:1``,
``thermal_expansion``.

Rules (`parse_spec`):

- names are exact (lower case); an unknown name is an error listing the valid ones;
- an effect that acts on joints (``EFFECTS[name] is True``) given without joints acts on
  all joints 1..n; joint numbers are 1..n, listed with commas, surrounding spaces ignored;
  repeats are merged and the joints sorted (``backlash:3,1,3`` is ``backlash:1,3``);
- an effect that does not act on joints given joints is an error;
- ``geometric`` is always part of a model and is not an effect to ask for;
- an effect with orders (``takes_orders``, e.g. ``joint_periodic``) gives each joint its
  orders after ``@``, joined by ``+``: ``joint_periodic:2@20+29`` or
  ``joint_periodic:1@12+22,2@20+29``; orders are integers >= 1, sorted and merged; every
  joint of such an effect needs them, and no other effect takes them.

`parse_specs` merges repeated names (``backlash:1`` and ``backlash:3`` give
``backlash:1,3``) rather than rejecting them, keeping the order of first appearance.
"""

from __future__ import annotations

import difflib
import numbers
import re
from dataclasses import dataclass

from torchcal.effects.registry import TakesJoints, lookup
from torchcal.errors import InputError

#: effect name -> whether it acts on (a subset of) the joints: a live read-only view of
#: the one registry `torchcal.effects.registry.REGISTRY` (built-in effects, user modules
#: loaded with ``--effects-module`` and installed packages' ``torchcal.effects`` entry points).
EFFECTS = TakesJoints()

_FORM = "NAME or NAME:J[,J...] with 1-based joint numbers"
_JOINT_RE = re.compile(r"[0-9]+", re.ASCII)


def takes_orders(name: str) -> bool:
    """Whether the registered effect `name` lists orders per joint (``J@K+K``)."""
    return bool(getattr(lookup(name), "takes_orders", False))


def format_spec(name: str, joints=(), orders=()) -> str:
    """``name``, ``name:2,3`` or, with orders (one tuple per joint), ``name:2@20+29,3@18``."""
    if not joints:
        return name
    if not orders:
        return f"{name}:{','.join(map(str, joints))}"
    return f"{name}:" + ",".join(f"{j}@{'+'.join(map(str, ks))}" for j, ks in zip(joints, orders))


@dataclass(frozen=True)
class EffectSpec:
    """One physical effect, and the joints it acts on.

    Attributes:
        name: a key of `EFFECTS` (a registered effect).
        joints: 1-based joint numbers, sorted and unique; empty exactly when the effect
            does not act on joints.
        orders: for an effect with orders, one sorted tuple of orders per joint (aligned
            with `joints`); else empty.

    ``str(spec)`` is ``"name"``, ``"name:2,3"`` or ``"name:2@20+29"`` and parses back to an
    equal spec.
    """

    name: str
    joints: tuple[int, ...] = ()
    orders: tuple[tuple[int, ...], ...] = ()

    def __post_init__(self):
        if self.name not in EFFECTS:
            raise UnknownEffectError(_unknown(self.name, self.name))
        try:
            joints = tuple(self.joints)
        except TypeError:
            raise InputError(f"EffectSpec.joints: expected a tuple of joint numbers, got {self.joints!r}") from None
        for j in joints:
            if isinstance(j, bool) or not isinstance(j, numbers.Integral) or j < 1:
                raise InputError(f"EffectSpec {self.name}: joint numbers are integers >= 1, got {j!r}")
        if takes_orders(self.name):
            per = dict(zip(joints, self.orders)) if len(self.orders) == len(joints) else {}
            if not per and joints:
                raise InputError(f"EffectSpec {self.name}: one tuple of orders per joint expected, "
                                 f"got {self.orders!r} for joints {joints}")
            bad = [k for ks in per.values() for k in ks
                   if isinstance(k, bool) or not isinstance(k, numbers.Integral) or k < 1]
            if bad or any(not ks for ks in per.values()):
                raise InputError(f"EffectSpec {self.name}: every joint needs orders, integers >= 1 "
                                 f"(e.g. {self.name}:2@20+29), got {self.orders!r}")
            orders = tuple(tuple(sorted({int(k) for k in per[j]})) for j in sorted(set(per)))
        elif self.orders:
            raise InputError(f"EffectSpec {self.name}: this effect takes no orders, got {self.orders!r}")
        else:
            orders = ()
        joints = tuple(sorted({int(j) for j in joints}))
        if EFFECTS[self.name] and not joints:
            raise InputError(f"EffectSpec {self.name}: this effect acts on joints; give at least one")
        if not EFFECTS[self.name] and joints:
            raise InputError(f"EffectSpec {self.name}: this effect takes no joints, got {joints}")
        object.__setattr__(self, "joints", joints)
        object.__setattr__(self, "orders", orders)

    @property
    def takes_joints(self) -> bool:
        """Whether this effect acts on joints."""
        return EFFECTS[self.name]

    def __str__(self) -> str:
        return format_spec(self.name, self.joints, self.orders)


class UnknownEffectError(InputError):
    """An effect spec names no registered effect. Its message ends with `HINT` (how a
    library caller registers an effect of its own); the command line names its option instead."""

    HINT = "(an effect of your own: register it first, torchcal.effects.register_effect or load_module)"


def _unknown(name: str, text: str) -> str:
    valid = ", ".join(sorted(EFFECTS))
    hint = difflib.get_close_matches(str(name).lower(), EFFECTS, n=1)
    did = f" (did you mean {hint[0]!r}?)" if hint else ""
    if str(name).strip().lower() == "geometric":
        return (f"effect spec {text!r}: 'geometric' is always part of the model; leave it out "
                f"(optional effects: {valid})")
    return (f"effect spec {text!r}: unknown effect {name!r}{did}; expected one of {valid} "
            + UnknownEffectError.HINT)


def _check_n(n_joints) -> int:
    if isinstance(n_joints, bool) or not isinstance(n_joints, numbers.Integral) or n_joints < 1:
        raise InputError(f"n_joints must be a positive integer, got {n_joints!r}")
    return int(n_joints)


def parse_spec(text, n_joints: int) -> EffectSpec:
    """Parse one effect spec ``NAME`` or ``NAME:J[,J...]`` for a robot with `n_joints`.

    Raises InputError (one line naming the spec and what was expected) for an empty or
    malformed spec, an unknown name, a joint number outside 1..n_joints, or joints given to
    an effect that takes none.

    Example: ``parse_spec("joint_compliance:3,2", 6)`` -> ``EffectSpec("joint_compliance", (2, 3))``;
    ``parse_spec("backlash", 6)`` -> joints (1, ..., 6).
    """
    n = _check_n(n_joints)
    if not isinstance(text, str):
        raise InputError(f"effect spec {text!r}: expected text, {_FORM}")
    name, sep, rest = text.strip().partition(":")
    name = name.strip()
    if not name:
        raise InputError(f"effect spec {text!r}: empty effect name; expected {_FORM}")
    if name not in EFFECTS:
        raise UnknownEffectError(_unknown(name, text))
    if not sep:
        if takes_orders(name):
            raise InputError(f"effect spec {text!r}: give joints and their orders, e.g. {name}:2@20+29 "
                             f"(discover finds them)")
        return EffectSpec(name, tuple(range(1, n + 1)) if EFFECTS[name] else ())
    if not EFFECTS[name]:
        raise InputError(f"effect spec {text!r}: effect {name!r} takes no joints; "
                         f"write it as {name!r}")
    if not rest.strip():
        raise InputError(f"effect spec {text!r}: expected joint numbers after ':', e.g. {name}:1,2")
    joints, orders, with_orders = [], {}, takes_orders(name)
    for item in rest.split(","):
        item, at, ks = item.strip().partition("@")
        item = item.strip()
        if not item:
            raise InputError(f"effect spec {text!r}: empty joint number; expected "
                             f"comma-separated joints 1..{n}, e.g. {name}:1,2")
        if with_orders != bool(at):
            need = f"joint {item} needs its orders, e.g. {name}:{item}@20+29" if with_orders else \
                f"effect {name!r} takes no orders ('@')"
            raise InputError(f"effect spec {text!r}: {need}")
        if at:
            ks = [k.strip() for k in ks.split("+")]
            if not all(_JOINT_RE.fullmatch(k) and len(k) <= 6 and int(k) >= 1 for k in ks):
                raise InputError(f"effect spec {text!r}: orders of joint {item} are integers >= 1 "
                                 f"joined by '+', e.g. {name}:{item}@20+29")
        if not _JOINT_RE.fullmatch(item):
            raise InputError(f"effect spec {text!r}: joint {item!r} is not a joint number; "
                             f"expected integers 1..{n}")
        j = int(item) if len(item) <= 18 else n + 1  # no int() of huge digit strings
        if not 1 <= j <= n:
            raise InputError(f"effect spec {text!r}: joint {item} out of range; the robot has "
                             f"joints 1..{n}")
        joints.append(j)
        if at:  # a repeated joint merges its orders
            orders.setdefault(j, set()).update(int(k) for k in ks)
    if with_orders:
        return EffectSpec(name, tuple(orders), tuple(tuple(ks) for ks in orders.values()))
    return EffectSpec(name, tuple(joints))


def parse_specs(texts, n_joints: int) -> tuple[EffectSpec, ...]:
    """Parse several effect specs; repeated names merge their joints.

    `texts`: an iterable of spec strings or `EffectSpec`s (a single string is one spec).
    Returns one EffectSpec per distinct name, in order of first appearance; an
    `EffectSpec` passed in is checked against `n_joints` too.
    """
    n = _check_n(n_joints)
    if isinstance(texts, (str, EffectSpec)):
        texts = [texts]
    merged: dict[str, dict[int, set[int]]] = {}
    for t in texts:
        if isinstance(t, EffectSpec):
            if t.joints and t.joints[-1] > n:
                raise InputError(f"effect spec {str(t)!r}: joint {t.joints[-1]} out of range; "
                                 f"the robot has joints 1..{n}")
            spec = t
        else:
            spec = parse_spec(t, n)
        per = merged.setdefault(spec.name, {})
        for i, j in enumerate(spec.joints):
            per.setdefault(j, set()).update(spec.orders[i] if spec.orders else ())
    return tuple(EffectSpec(name, tuple(per), tuple(tuple(ks) for ks in per.values()) if takes_orders(name) else ())
                 for name, per in merged.items())
