"""Builders for structured systems: templates over index arrays, particle systems."""
from dolfinode.systems.particles import ParticleSystem, lattice, lattice_system
from dolfinode.systems.template import StateNames, Template, TemplateODE

__all__ = ["ParticleSystem", "StateNames", "Template", "TemplateODE", "lattice",
           "lattice_system"]
