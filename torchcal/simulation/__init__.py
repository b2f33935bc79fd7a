"""Simulation: a virtual robot that carries errors its fitted model may lack (poses: `torchcal.robots.random_poses`).
"""

from torchcal._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "torchcal.simulation.session": ["Simulation", "simulate"],
    "torchcal.simulation.virtual_robot": ["VirtualRobot", "default_masses"],
})
