"""Simulation: raw-ADC cubes, bodies, trajectories and radar networks."""
