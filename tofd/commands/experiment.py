"""Run the paper's experiments: `tofd experiment sphere` (eps0 at a sphere's apex vs distance, FFT vs NFFT)."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", choices=["sphere"], help="which experiment")
    parser.add_argument("--out", default="experiments/sphere", help="output directory (PNG plot and JSON)")
    parser.add_argument("--config", default=None, help="config file (default: the bundled config/tofd.toml)")


def main(args: argparse.Namespace) -> int:
    import json

    from tofd.config import load_config
    from tofd.lab import sphere_experiment as experiment_sphere
    from tofd.outputs import prepare_output_dir, write_text

    cfg = load_config(args.config)
    import matplotlib  # noqa: F401 (the plot's: without the lab extra, stop here, not after the computation)

    out = prepare_output_dir(args.out)
    points = experiment_sphere.run(cfg.intrinsics, cfg.features)
    print(experiment_sphere.table(points))
    result = experiment_sphere.to_json(points, cfg.features)
    write_text(out / "sphere.json", json.dumps(result, indent=2) + "\n")
    experiment_sphere.plot(points, cfg.features.equivalence_range_m, out / "sphere.png")
    s = result["summary"]
    print(f"NFFT eps0 spread {100 * s['nfft_eps0_spread']:.2f} %, FFT/NFFT at e {s['fft_over_nfft_at_e']:.3f}, "
          f"FFT monotone: {s['fft_monotone']}")
    print(f"wrote {out / 'sphere.json'} and {out / 'sphere.png'}")
    return 0
