//! Fourier-Mellin registration. (Being written.)
