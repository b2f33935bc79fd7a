"""Effect specs: vocabulary, parser rules, error messages, property-based round trips."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from torchcal.errors import InputError
from torchcal.effects.spec import EFFECTS, EffectSpec, parse_spec, parse_specs, takes_orders

JOINT_EFFECTS = sorted(k for k, v in EFFECTS.items() if v)
PLAIN_EFFECTS = sorted(k for k, v in EFFECTS.items() if not v)


def test_vocabulary_matches_design():
    assert EFFECTS == {"base_frame": False, "tool_offset": False, "joint_compliance": True,
                       "gear_periodic": True, "backlash": True, "encoder_scale": True,
                       "thermal_expansion": False, "joint_clearance": True, "cross_coupling": True,
                       "axis_tilt": True, "base_compliance": False, "link_bending": True,
                       "gear_transmission": True, "joint_periodic": True}


@pytest.mark.parametrize("text,name,joints,as_str", [
    ("joint_compliance:2,3", "joint_compliance", (2, 3), "joint_compliance:2,3"),
    ("gear_periodic:1", "gear_periodic", (1,), "gear_periodic:1"),
    ("thermal_expansion", "thermal_expansion", (), "thermal_expansion"),
    ("backlash", "backlash", (1, 2, 3, 4, 5, 6), "backlash:1,2,3,4,5,6"),  # all joints
    ("backlash:3,1,3", "backlash", (1, 3), "backlash:1,3"),  # sorted, repeats merged
    ("  encoder_scale : 6 , 2 ", "encoder_scale", (2, 6), "encoder_scale:2,6"),
    ("base_frame", "base_frame", (), "base_frame"),
])
def test_parse_spec(text, name, joints, as_str):
    spec = parse_spec(text, 6)
    assert spec == EffectSpec(name, joints)
    assert str(spec) == as_str
    assert spec.takes_joints == EFFECTS[name]


@pytest.mark.parametrize("text,match", [
    ("", r"effect spec '': empty effect name; expected NAME or NAME:J\[,J\.\.\.\]"),
    ("   ", r"effect spec '   ': empty effect name"),
    (":1", r"effect spec ':1': empty effect name"),
    ("backlash:", r"effect spec 'backlash:': expected joint numbers after ':', e\.g\. backlash:1,2"),
    ("backlash:a", r"effect spec 'backlash:a': joint 'a' is not a joint number; expected integers 1\.\.6"),
    ("backlash:-1", r"joint '-1' is not a joint number"),
    ("backlash:1.5", r"joint '1\.5' is not a joint number"),
    ("backlash:0", r"effect spec 'backlash:0': joint 0 out of range; the robot has joints 1\.\.6"),
    ("backlash:7", r"effect spec 'backlash:7': joint 7 out of range"),
    ("backlash:" + "9" * 5000, r"out of range"),
    ("backlash:1,,2", r"effect spec 'backlash:1,,2': empty joint number; expected comma-separated joints 1\.\.6"),
    ("backlash:1,", r"empty joint number"),
    ("backlash:1:2", r"joint '1:2' is not a joint number"),
    ("base_frame:1", r"effect spec 'base_frame:1': effect 'base_frame' takes no joints; write it as 'base_frame'"),
    ("thermal_expansion:", r"effect 'thermal_expansion' takes no joints"),
    ("foo", r"effect spec 'foo': unknown effect 'foo'; expected one of axis_tilt, backlash, base_compliance, "
            r"base_frame, cross_coupling, encoder_scale, gear_periodic, gear_transmission, joint_clearance, "
            r"joint_compliance, joint_periodic, link_bending, thermal_expansion, tool_offset"),
    ("backlsh:1", r"unknown effect 'backlsh' \(did you mean 'backlash'\?\); expected one of"),
    ("Backlash", r"unknown effect 'Backlash' \(did you mean 'backlash'\?\)"),
    ("geometric", r"'geometric' is always part of the model; leave it out"),
])
def test_parse_spec_errors(text, match):
    with pytest.raises(ValueError, match=match) as info:
        parse_spec(text, 6)
    assert issubclass(info.type, InputError)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("bad", [0, -1, 2.5, True, "6", None])
def test_bad_n_joints(bad):
    with pytest.raises(InputError, match=r"n_joints must be a positive integer"):
        parse_spec("backlash", bad)


def test_not_text():
    with pytest.raises(InputError, match=r"effect spec 3: expected text"):
        parse_spec(3, 6)


def test_effect_spec_checks():
    with pytest.raises(InputError, match=r"unknown effect 'nope'"):
        EffectSpec("nope")
    with pytest.raises(InputError, match=r"EffectSpec backlash: this effect acts on joints"):
        EffectSpec("backlash")
    with pytest.raises(InputError, match=r"EffectSpec base_frame: this effect takes no joints"):
        EffectSpec("base_frame", (1,))
    with pytest.raises(InputError, match=r"joint numbers are integers >= 1, got 0"):
        EffectSpec("backlash", (0,))
    assert EffectSpec("backlash", [3, 1, 3]).joints == (1, 3)
    assert hash(EffectSpec("backlash", (1,))) == hash(EffectSpec("backlash", [1]))


def test_parse_specs_merges_same_name():
    specs = parse_specs(["backlash:3", "thermal_expansion", "backlash:1", "gear_periodic:2",
                         "thermal_expansion"], 6)
    assert [str(s) for s in specs] == ["backlash:1,3", "thermal_expansion", "gear_periodic:2"]
    assert [str(s) for s in parse_specs(["backlash:2", "backlash"], 3)] == ["backlash:1,2,3"]
    assert parse_specs("encoder_scale:2", 6) == (EffectSpec("encoder_scale", (2,)),)
    assert parse_specs([EffectSpec("backlash", (2,)), "backlash:1"], 6) == (EffectSpec("backlash", (1, 2)),)
    assert parse_specs([], 6) == ()
    with pytest.raises(InputError, match=r"effect spec 'backlash:7': joint 7 out of range"):
        parse_specs([EffectSpec("backlash", (7,))], 6)
    with pytest.raises(InputError, match=r"effect spec 'nope'"):
        parse_specs(["backlash", "nope"], 6)


# -- property-based ---------------------------------------------------------------------

@st.composite
def specs(draw):
    n = draw(st.integers(1, 12))
    name = draw(st.sampled_from(sorted(EFFECTS)))
    joints = tuple(draw(st.sets(st.integers(1, n), min_size=1))) if EFFECTS[name] else ()
    orders = tuple(tuple(draw(st.sets(st.integers(1, 200), min_size=1))) for _ in joints) if takes_orders(name) else ()
    return EffectSpec(name, joints, orders), n


@settings(max_examples=100, deadline=None)
@given(specs())
def test_property_str_round_trip(spec_n):
    spec, n = spec_n
    again = parse_spec(str(spec), n)
    assert again == spec
    assert str(again) == str(spec)


@settings(max_examples=100, deadline=None)
@given(st.text(max_size=40)
       | st.text(alphabet=st.sampled_from(list("backlash_joint:gear,0123456789 -.")), max_size=40)
       | st.builds(lambda name, rest: name + rest, st.sampled_from(sorted(EFFECTS)),
                   st.text(alphabet=st.sampled_from(list(":,0123456789 a@+")), max_size=12)),
       st.integers(1, 8))
def test_property_random_text_parses_or_inputerror(text, n):
    try:
        spec = parse_spec(text, n)
    except InputError as exc:
        assert "\n" not in str(exc)  # one line: the spec is quoted with repr
        return
    assert spec.name in EFFECTS and all(1 <= j <= n for j in spec.joints)
    assert parse_spec(str(spec), n) == spec
