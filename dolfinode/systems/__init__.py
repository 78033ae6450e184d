"""Builders for structured systems: templates over index arrays, particle systems."""
from dolfinode.systems.template import StateNames, Template, TemplateODE

__all__ = ["StateNames", "Template", "TemplateODE"]
