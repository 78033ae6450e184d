"""Galerkin time-stepping methods: cG(q) on Lobatto nodes and dG(q) on right Radau nodes."""
from dolfinode.methods.method import Method, make_method, parse_method

__all__ = ["Method", "make_method", "parse_method"]
