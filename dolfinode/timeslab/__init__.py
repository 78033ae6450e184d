"""Time slabs: the compiled loops that build, solve and check one slab after another."""
