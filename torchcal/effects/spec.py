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
- ``geometric`` is always part of a model and is not an effect to ask for.

`parse_specs` merges repeated names (``backlash:1`` and ``backlash:3`` give
``backlash:1,3``) rather than rejecting them, keeping the order of first appearance.
"""

from __future__ import annotations

import difflib
import numbers
import re
from dataclasses import dataclass

from torchcal.effects.registry import TakesJoints
from torchcal.errors import InputError

#: effect name -> whether it acts on (a subset of) the joints: a live read-only view of
#: the one registry `torchcal.effects.registry.REGISTRY` (built-in effects, user modules
#: loaded with ``--effects-module`` and installed packages' ``torchcal.effects`` entry points).
EFFECTS = TakesJoints()

_FORM = "NAME or NAME:J[,J...] with 1-based joint numbers"
_JOINT_RE = re.compile(r"[0-9]+", re.ASCII)


@dataclass(frozen=True)
class EffectSpec:
    """One physical effect, and the joints it acts on.

    Attributes:
        name: a key of `EFFECTS` (a registered effect).
        joints: 1-based joint numbers, sorted and unique; empty exactly when the effect
            does not act on joints.

    ``str(spec)`` is ``"name"`` or ``"name:2,3"`` and parses back to an equal spec.
    """

    name: str
    joints: tuple[int, ...] = ()

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
        joints = tuple(sorted({int(j) for j in joints}))
        if EFFECTS[self.name] and not joints:
            raise InputError(f"EffectSpec {self.name}: this effect acts on joints; give at least one")
        if not EFFECTS[self.name] and joints:
            raise InputError(f"EffectSpec {self.name}: this effect takes no joints, got {joints}")
        object.__setattr__(self, "joints", joints)

    @property
    def takes_joints(self) -> bool:
        """Whether this effect acts on joints."""
        return EFFECTS[self.name]

    def __str__(self) -> str:
        if not self.joints:
            return self.name
        return f"{self.name}:{','.join(str(j) for j in self.joints)}"


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
        return EffectSpec(name, tuple(range(1, n + 1)) if EFFECTS[name] else ())
    if not EFFECTS[name]:
        raise InputError(f"effect spec {text!r}: effect {name!r} takes no joints; "
                         f"write it as {name!r}")
    if not rest.strip():
        raise InputError(f"effect spec {text!r}: expected joint numbers after ':', e.g. {name}:1,2")
    joints = []
    for item in rest.split(","):
        item = item.strip()
        if not item:
            raise InputError(f"effect spec {text!r}: empty joint number; expected "
                             f"comma-separated joints 1..{n}, e.g. {name}:1,2")
        if not _JOINT_RE.fullmatch(item):
            raise InputError(f"effect spec {text!r}: joint {item!r} is not a joint number; "
                             f"expected integers 1..{n}")
        j = int(item) if len(item) <= 18 else n + 1  # no int() of huge digit strings
        if not 1 <= j <= n:
            raise InputError(f"effect spec {text!r}: joint {item} out of range; the robot has "
                             f"joints 1..{n}")
        joints.append(j)
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
    merged: dict[str, set[int]] = {}
    for t in texts:
        if isinstance(t, EffectSpec):
            if t.joints and t.joints[-1] > n:
                raise InputError(f"effect spec {str(t)!r}: joint {t.joints[-1]} out of range; "
                                 f"the robot has joints 1..{n}")
            spec = t
        else:
            spec = parse_spec(t, n)
        merged.setdefault(spec.name, set()).update(spec.joints)
    return tuple(EffectSpec(name, tuple(js)) for name, js in merged.items())
