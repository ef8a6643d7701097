"""Runnable examples: ``python -m squkf.examples.g13ej_example``."""
