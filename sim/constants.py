"""Physical constants shared by every model, with their sources.

Earth gravity constants are those of EGM96 / WGS 84 so that J2 and the reference radius belong to
one model (mixing a J2 from one model with a radius from another is a 1e-7 relative error).
"""

#: Earth gravitational parameter, m^3/s^2 (EGM96 / WGS 84).
MU_EARTH = 3.986004418e14
#: Earth equatorial radius, m (WGS 84).
R_EARTH = 6378137.0
#: Unnormalised second zonal harmonic J2 = -C20 (EGM96, tide-free).
J2_EARTH = 1.08262668e-3
#: Earth rotation rate, rad/s (IERS Conventions 2010, nominal).
OMEGA_EARTH = 7.292115e-5
#: IGRF reference radius, m.
R_IGRF = 6371200.0
#: Speed of light, m/s.
C_LIGHT = 299792458.0
#: Astronomical unit, m (IAU 2012).
AU = 149597870700.0
#: Seconds per day.
DAY_S = 86400.0
