"""Pure metric functions of arrays and valid masks (shapes in each docstring)."""
