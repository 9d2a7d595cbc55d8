"""ifmi: extended improved Fourier-Mellin invariant rotation estimation for omni images."""

__version__ = "0.1.0"
