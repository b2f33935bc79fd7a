"""Data that lack a column an effect of the model reads: `check_conditions`.

An effect that reads a recorded condition (``thermal_expansion`` the ``temp_c`` column, a
per-point ``tool_offset`` the ``point`` ids) refuses data without it (its
`check_context`); this check makes that refusal name the file, and runs it before any
other check so that no command first computes with the missing column (a traceback).
"""

from __future__ import annotations

from torchcal.errors import InputError


def check_conditions(model, m, where: str | None = None) -> None:
    """InputError '<where>: <the effect's words>' when the `Measurements` m lack what an
    effect of `model` (`CalibrationModel`) needs; `where` defaults to m's source."""
    from torchcal.effects import context_of

    what = where or m.source or "measurements"
    try:
        model.check_context(context_of(model.robot, m))
    except InputError as exc:
        msg = str(exc)
        raise InputError(msg if msg.startswith(f"{what}:") else f"{what}: {msg}") from None
