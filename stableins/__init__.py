"""stableins: on-system accelerometer calibration for space-stable inertial navigation systems.

The package is laid out as the pipeline it implements::

    conventions, errormodel, platform      physics (frames, error model, gimbals)
    simulator                              the independent truth world
    data, records                          file formats and calibration records
    estimators                             coarse, fine and system-level stages
    discovery                              compare, rank missing effects, refit
    procedures, drivers                    step-by-step execution on a platform
    reporting                              PDF calibration reports

Heavy dependencies (numpy, scipy, filterpy, matplotlib) are imported by the
submodules that need them, never here, so ``stableins --help`` stays fast.
"""

__version__ = "0.1.0"
