class HardwareConfigError(ValueError):
    """A hardware configuration table that cannot be used: unknown key, bad value, missing field."""
