"""Optics: projector geometry, materials, spectra, propagation engines and the PSF bank."""
