"""hydroplant hydraulic network (no MuJoCo import)."""

# numba's cache folder and CPU target are chosen before any module imports numba (hydraulics.kernel_cache)
from hydraulics import kernel_cache as _kernel_cache  # noqa: F401
