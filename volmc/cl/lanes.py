"""Lane width W: the paths one work-item of the lane-generic kernels traces in lock-step
(kernels/lanes.h; docs/lanes.md).

The default is the device's preferred float vector width (``preferred_vector_width_float``:
16 on AVX-512 CPUs under PoCL, 8 on AVX2, 1 on GPUs), rounded down to a width the kernels
are built for. ``--lanes N`` (CLI), ``lanes=`` (API) and the environment variable
VOLMC_LANES override it. W is part of a render's identity: each lane traces exactly the
path the scalar kernel traces for its sample, but the vector and scalar maths libraries may
round differently (docs/lanes.md), so a checkpoint records W and a resume with another W
is refused.
"""

import os

from ..scene.errors import SceneError

#: The widths the kernels compile for.
LANE_WIDTHS = (1, 4, 8, 16)
ENV_VAR = "VOLMC_LANES"


def device_lanes(device):
    """The default W of a pyopencl Device: its preferred float vector width, rounded down to
    one of LANE_WIDTHS."""
    preferred = int(getattr(device, "preferred_vector_width_float", 1) or 1)
    return max(w for w in LANE_WIDTHS if w <= max(preferred, 1))


def check_lanes(value, file="command line", key="--lanes"):
    """``value`` as a lane width, or the one-line SceneError naming ``file`` and ``key``."""
    try:
        w = int(str(value).strip()) if not isinstance(value, int) else value
    except ValueError:
        w = None
    if isinstance(value, bool) or w not in LANE_WIDTHS:
        raise SceneError(file, key, f"lane width must be one of "
                                    f"{', '.join(map(str, LANE_WIDTHS))}, got {value!r}")
    return w


def resolve_lanes(lanes=None, device=None):
    """The lane width to build with: ``lanes`` if given, else $VOLMC_LANES, else the
    device's (``device``: a pyopencl Device or a --device spec; None: the default
    device)."""
    if lanes is not None:
        return check_lanes(lanes, "lanes", "lanes")
    env = os.environ.get(ENV_VAR)
    if env:
        return check_lanes(env, "environment", ENV_VAR)
    if device is None or isinstance(device, str):
        from .device import select_device
        device = select_device(device)
    return device_lanes(device)
