"""Blackbody emission: the table of linear-sRGB radiance against temperature that
``medium.emission.temperature`` reads (volmc/reference/medium.py ``emitted_radiance``).

Units and colour conversion (docs/colour_emission.md, "Emission"):

* Spectral radiance of a blackbody at temperature T (kelvin), Planck's law:
  B(lambda, T) = 2 h c^2 / lambda^5 / (exp(h c / (lambda k T)) - 1), in W sr^-1 m^-2 per
  metre of wavelength.
* CIE 1931 XYZ: X = 683 lm/W x integral of B x_bar over 360-830 nm (Y, Z alike), so Y is the
  luminance in nits (cd/m^2). The colour-matching functions are the multi-lobe Gaussian fit
  of Wyman, Sloan and Shirley (2013), accurate to about 1 % of the tabulated CIE 1931 2-degree
  observer, evaluated every nanometre.
* Linear sRGB (Rec. 709 primaries, D65 white) by the standard XYZ-to-sRGB matrix; the few
  negative components of deep-red low temperatures (outside the sRGB gamut) are clipped to 0.
* The scene's ``scale`` multiplies the result: Le = scale x RGB(T) (nits into the scene's
  radiance units). For orientation (``luminance``): 2.7 nits at 1000 K, 7.8e3 at 1500 K,
  4.7e5 at 2000 K, 3.0e7 at 3000 K: a factor of about 170 from 1000 to 1500 K, so the
  hottest part of a flame dominates.

Below 0 K, and at 0 K, Le is 0. Between table entries the renderer interpolates linearly in
temperature (BLACKBODY_TABLE_SIZE entries from 0 K to the hottest temperature of the scene).
"""

import numpy as np

from .constants import BLACKBODY_TABLE_SIZE

H = 6.62607015e-34       # Planck constant, J s
C_LIGHT = 2.99792458e8   # speed of light, m/s
K_B = 1.380649e-23       # Boltzmann constant, J/K
K_M = 683.0              # luminous efficacy at 555 nm, lm/W
#: Hottest temperatures below this (kelvin) emit nothing visible (under 1e-100 nits): the
#: table is then all zero, and its entries-per-kelvin factor stays finite in float32.
MIN_TABLE_KELVIN = 1.0

#: XYZ to linear sRGB (Rec. 709 primaries, D65 white).
XYZ_TO_SRGB = np.array([[3.2404542, -1.5371385, -0.4985314],
                        [-0.9692660, 1.8760108, 0.0415560],
                        [0.0556434, -0.2040259, 1.0572252]])

_LAMBDA = np.arange(360.0, 831.0, 1.0)   # nm


def _lobe(lam, mu, s1, s2):
    s = np.where(lam < mu, s1, s2)
    return np.exp(-0.5 * ((lam - mu) / s) ** 2)


def cie_xyz(lam):
    """CIE 1931 2-degree colour-matching functions (x_bar, y_bar, z_bar) at wavelengths
    ``lam`` (nm), by Wyman, Sloan and Shirley's multi-lobe fit."""
    x = (1.056 * _lobe(lam, 599.8, 37.9, 31.0) + 0.362 * _lobe(lam, 442.0, 16.0, 26.7)
         - 0.065 * _lobe(lam, 501.1, 20.4, 26.2))
    y = 0.821 * _lobe(lam, 568.8, 46.9, 40.5) + 0.286 * _lobe(lam, 530.9, 16.3, 31.1)
    z = 1.217 * _lobe(lam, 437.0, 11.8, 36.0) + 0.681 * _lobe(lam, 459.0, 26.0, 13.8)
    return x, y, z


def planck(lam_nm, T):
    """Blackbody spectral radiance B(lambda, T) in W sr^-1 m^-2 nm^-1 (lambda in nm, T in
    kelvin; 0 for T <= 0)."""
    lam = np.asarray(lam_nm, np.float64) * 1e-9
    T = np.asarray(T, np.float64)
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        b = 2.0 * H * C_LIGHT**2 / lam**5 / np.expm1(H * C_LIGHT / (lam * K_B * T)) * 1e-9
    return np.where(T > 0, np.nan_to_num(b, nan=0.0, posinf=0.0), 0.0)


def blackbody_xyz(T):
    """CIE XYZ of blackbodies at temperatures T (kelvin, any shape), Y in nits: shape
    T.shape + (3,)."""
    T = np.asarray(T, np.float64)
    x, y, z = cie_xyz(_LAMBDA)
    b = planck(_LAMBDA, T[..., None])          # per nm, 1 nm steps
    return K_M * np.stack([(b * x).sum(-1), (b * y).sum(-1), (b * z).sum(-1)], -1)


def blackbody_rgb(T):
    """Linear-sRGB radiance (nits) of blackbodies at temperatures T (kelvin): shape
    T.shape + (3,), negative components clipped to 0."""
    return np.maximum(blackbody_xyz(T) @ XYZ_TO_SRGB.T, 0.0)


def luminance(T):
    """Luminance (nits) of a blackbody at temperature T (kelvin)."""
    return blackbody_xyz(T)[..., 1]


def blackbody_table(t_max):
    """(table [BLACKBODY_TABLE_SIZE, 3], entries per kelvin): linear-sRGB blackbody radiance
    at temperatures i t_max / (BLACKBODY_TABLE_SIZE - 1), i = 0 .. size - 1."""
    n = BLACKBODY_TABLE_SIZE
    if not t_max >= MIN_TABLE_KELVIN:   # nothing visible; and (n - 1) / t_max stays finite
        return np.zeros((n, 3)), 0.0
    temps = np.linspace(0.0, t_max, n)
    return blackbody_rgb(temps), (n - 1) / t_max
