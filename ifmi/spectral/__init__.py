"""The iFMI front end: panorama, tiling, phase correlation, Fourier-Mellin registration, tile flow and the coarse stage."""
