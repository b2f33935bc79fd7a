"""Simulation: a virtual robot that carries errors its fitted model may lack (poses: `torchcal.robots.random_poses`)."""

from torchcal.simulation.virtual_robot import VirtualRobot, default_masses

__all__ = ["VirtualRobot", "default_masses"]
