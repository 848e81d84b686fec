"""hydroplant simulation layer."""

import functools

import hydraulics  # noqa: F401  (first: chooses numba's cache folder and CPU target, hydraulics.kernel_cache)


@functools.lru_cache(maxsize=1)
def version() -> str:
    """The installed hydroplant version, or ``"unknown"`` (read once per process: the lookup costs ≈ 1 ms)."""
    import importlib.metadata

    try:
        return importlib.metadata.version("hydroplant")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"
