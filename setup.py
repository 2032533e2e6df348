"""The package's one compiled part, canfdi._ckernel (the C core in canfdi/_c), as an optional
setuptools Extension: where no compiler exists the build goes on without it and the numpy
kernel runs (everything else is in pyproject.toml)."""
from setuptools import Extension, setup

setup(ext_modules=[Extension(
    "canfdi._ckernel",
    sources=["canfdi/_c/_kernel.c", "canfdi/_c/announce.c", "canfdi/_c/bank.c",
             "canfdi/_c/compensate.c", "canfdi/_c/counter.c", "canfdi/_c/decide.c",
             "canfdi/_c/decisions.c", "canfdi/_c/decode.c", "canfdi/_c/detect.c",
             "canfdi/_c/diagnose.c", "canfdi/_c/drive.c", "canfdi/_c/drive_init.c",
             "canfdi/_c/e2e.c", "canfdi/_c/encode.c", "canfdi/_c/gate.c", "canfdi/_c/info.c",
             "canfdi/_c/lagged.c", "canfdi/_c/latest.c", "canfdi/_c/track.c",
             "canfdi/_c/track_check.c"],
    depends=["canfdi/_c/cfdi.h", "canfdi/_c/decode.h", "canfdi/_c/drive.h",
             "canfdi/_c/drive_impl.h", "canfdi/_c/e2e.h", "canfdi/_c/encode.h",
             "canfdi/_c/lagged.h", "canfdi/_c/track.h"],
    include_dirs=["canfdi/_c"],
    define_macros=[("Py_LIMITED_API", "0x030B0000")],
    py_limited_api=True,
    extra_compile_args=["-std=c99", "-Wall", "-Wextra", "-Werror", "-ffp-contract=off",
                        "-fno-strict-aliasing"],
    optional=True,
)])
