"""Handler of ``nmsid twin export TWIN.json --fmu --out P01.fmu`` (registered by
:mod:`nmsid.cli.identify`)."""

from __future__ import annotations

from nmsid.export.fmu.build import export_fmu


def run_twin_export(args) -> int:
    """Write the FMU and say what it holds."""
    result = export_fmu(args.twin, args.out, force=args.force, extrapolate=args.extrapolate,
                        binary=not args.sources_only)
    binary = (f"binary for {result.platform}" if result.platform else
              "sources only (no binary)")
    print(f"wrote {result.path}: FMI 2.0 co-simulation + model exchange, model identifier "
          f"{result.model_identifier}, {binary}, in {result.seconds:.2f} s")
    return 0
