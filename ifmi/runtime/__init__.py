"""Process-level support shared by both command lines: interrupts, local workers, warnings as lines."""
