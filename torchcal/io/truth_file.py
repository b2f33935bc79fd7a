"""The true parameters of a simulated session, as ``torchcal simulate --truth`` writes them:
``{"robot", "seed", "effects", "parameters": {name: {"value", "unit"}}}`` in degrees and
mm, the units of MODEL.json (`torchcal.io.modelfile.file_units`)."""

from __future__ import annotations

import torch


def truth_to_dict(sim) -> dict:
    """The truth JSON of a `torchcal.simulation.session.Simulation`."""
    from torchcal.calibration.model import CalibrationModel
    from torchcal.io.modelfile import file_units

    units, k = file_units(CalibrationModel(sim.robot, sim.effects))
    values = (sim.theta.detach().to("cpu", torch.float64) * k).tolist()
    return {"robot": sim.robot.name, "seed": sim.seed, "effects": list(sim.effects),
            "parameters": {n: {"value": v, "unit": u} for n, v, u in zip(sim.parameter_names, values, units)}}
