"""Pure imaging for the stand: star catalog, bench geometry, renderer, bright bodies, calibration, outputs."""
