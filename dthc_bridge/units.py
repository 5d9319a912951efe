"""Unit constants every layer shares (the material library, the controller, a program's
modal state, the mock's gantry): defined once, importing nothing."""

__all__ = ["MM_PER_INCH"]

MM_PER_INCH = 25.4  # exact, by definition of the inch
