"""Identification of the isolator: equation error, variable projection, output error."""
