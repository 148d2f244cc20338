"""Lane width W: the paths one work-item of the lane-generic kernels traces in lock-step
(kernels/lanes.h; docs/lanes.md).

The default is the device's preferred float vector width (``preferred_vector_width_float``:
16 on AVX-512 CPUs under PoCL, 8 on AVX2, 1 on GPUs), rounded down to a width the kernels
are built for. ``--lanes N`` (CLI), ``lanes=`` (API) and the environment variable
VOLMC_LANES override it. W is part of a render's identity: each lane traces exactly the
path the scalar kernel traces for its sample, but the vector and scalar maths libraries may
round differently (docs/lanes.md), so a checkpoint records W and a resume with another W
is refused.

How a lane's gather loads reach memory is the other choice per device (``gathers``): as one
vector gather instruction, or as W scalar loads. It changes the speed only, never a value
loaded, so images are the same bit for bit either way.
"""

import os
from pathlib import Path

from ..scene.errors import SceneError

#: The widths the kernels compile for.
LANE_WIDTHS = (1, 4, 8, 16)
ENV_VAR = "VOLMC_LANES"
#: How gathers load: "instructions" (the vector gather instruction LLVM makes of a
#: lane-by-lane load loop) or "loads" (W scalar loads, kept apart by volatile).
GATHER_KINDS = ("instructions", "loads")
GATHER_ENV = "VOLMC_GATHERS"
#: Linux's report of Intel's Gather Data Sampling mitigation, whose microcode slows the
#: gather instructions down.
GDS_STATUS = Path("/sys/devices/system/cpu/vulnerabilities/gather_data_sampling")


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


def device_gathers(device, gds_status=GDS_STATUS):
    """The default gather kind of a pyopencl Device (docs/lanes.md, "Gathers"). Measured at
    W = 16 (`volmc bench render --baseline`): on an AMD Zen 5 the scalar loads were 1.07x to
    1.10x faster, on a Zen 3 at W = 8 the two were equal, on an Intel Xeon with AVX-512
    (Sapphire Rapids class) the instructions were 1.12x to 1.34x faster. So CPUs take the
    instructions when Intel made them and the loads otherwise; an Intel CPU whose kernel
    reports the Gather Data Sampling microcode mitigation takes the loads, since that
    microcode is what slows its gathers. Other devices (GPUs, at W = 1 by default) take the
    instructions, as the plain code they are."""
    import pyopencl as cl
    if not (int(getattr(device, "type", 0)) & cl.device_type.CPU):
        return "instructions"
    vendor = str(getattr(device, "vendor", ""))
    if "intel" not in vendor.lower():
        return "loads"
    try:
        status = Path(gds_status).read_text()
    except OSError:
        status = ""
    # ("Mitigation: Microcode" or "... (locked)"; not "Mitigation: AVX disabled, no microcode")
    return "loads" if status.strip().lower().startswith("mitigation: microcode") \
        else "instructions"


def resolve_gathers(device):
    """The gather kind to build with: $VOLMC_GATHERS if set (checked: one of GATHER_KINDS),
    else the device's."""
    env = os.environ.get(GATHER_ENV)
    if env:
        kind = env.strip().lower()
        if kind not in GATHER_KINDS:
            raise SceneError("environment", GATHER_ENV,
                             f"must be one of {', '.join(GATHER_KINDS)}, got {env!r}")
        return kind
    return device_gathers(device)


def lane_options(lanes, gathers):
    """Build options of a lane-generic program: its width and its gather kind (one of
    GATHER_KINDS, as resolve_gathers gives it)."""
    return [f"-DLANES={int(lanes)}", f"-DGATHER_SCALAR={int(gathers == 'loads')}"]
