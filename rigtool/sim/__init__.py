"""Simulator twin: thruster physics, device personalities and transport endpoints."""
