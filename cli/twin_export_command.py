"""Handler of ``nmsid twin export TWIN.json --fmu --out P01.fmu`` and ``nmsid export fmu
TWIN.json --out P01.fmu`` (registered by :mod:`nmsid.cli.identify` and
:mod:`nmsid.cli.export`)."""

from __future__ import annotations

from nmsid.export.fmu.build import export_fmu


def run_twin_export(args) -> int:
    """Write the FMU and say what it holds."""
    result = export_fmu(args.twin, args.out, force=args.force, extrapolate=args.extrapolate,
                        binary=not args.sources_only)
    binary = (f"binary for {result.platform}" if result.platform else
              "sources only (no binary)")
    joints = (f", joints {', '.join(result.joints)} (inputs rE_<joint>, sE_<joint>)"
              if result.joints else "")
    print(f"wrote {result.path}: FMI 2.0 co-simulation + model exchange, model identifier "
          f"{result.model_identifier}{joints}, {binary}, in {result.seconds:.2f} s")
    return 0
