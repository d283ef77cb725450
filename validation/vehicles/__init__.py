"""Vehicles: physics references, flight-test stand-ins and JSBSim aircraft, by registry name.

The registry (:mod:`validation.vehicles.registry`) is the public entry point; docs/vehicles.md
describes every vehicle and the effects each stand-in adds.
"""
from validation.vehicles.registry import Vehicle, get_vehicle, read_recording, vehicle_names

__all__ = ["Vehicle", "get_vehicle", "read_recording", "vehicle_names"]
