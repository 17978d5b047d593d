"""Train the nose detector's boxes (all four variants) and write the model JSON.

Trains on TRAIN (a dataset .npz or a recording with ground truth), by default the rendered train split: three
subjects at 0.60 m (--train-subjects names others). The box of each variant spans the [q, 1 - q] quantiles of
the log10 features of the pixels within --positive-radius-mm of the nose tip, its half-widths then rescaled per
feature to minimise the training per-image EER; its operating scale is the middle of
the training frames' zero-error scales, else their equal-error scale.

The shipped config/nose_model.json is trained, 80 frames each, on the five hand-made identities that are neither
the evaluation's test subject nor held out, the drawn face shapes and the ICT model's heads for training
(tofd.lab.faces CV_SUBJECTS and SHAPE_TRAIN_SUBJECTS; never SHAPE_TUNE_SUBJECTS or the held-out ones): tofd train
--train-subjects lps,mp,mp_broad,mp_chin,lps_flat,lps_s1,lps_s2,lps_s3,mp_s1,mp_s2,mp_s3,ict_1,ict_2,ict_3,ict_4,
ict_5,ict_6,ict_7,ict_8 --train-frames 1520 --out config/nose_model.json.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from tofd.lab.data_args import add_data_arguments

    add_data_arguments(parser, ("train",))
    parser.add_argument("--out", required=True, metavar="MODEL.json",
                        help="model file to write (use it with detector.model_path in the config)")
    parser.add_argument("--quantile", type=float, default=0.05, help="box quantile q (default 0.05)")
    parser.add_argument("--positive-radius-mm", type=float, default=5.0,
                        help="training pixels: within this 3-D distance of the nose tip (default 5)")


def main(args: argparse.Namespace) -> int:
    from tofd.algorithm.detector import Candidates, save_model
    from tofd.config import load_config
    from tofd.lab.data_args import check_data_arguments, dataset_for, samples_for
    from tofd.lab.evaluation import train_model
    from tofd.outputs import check_output_file

    cfg = load_config(args.config)
    check_data_arguments(args, ("train",))
    check_output_file(args.out)
    timing: dict = {}
    ds = dataset_for(args, "train", timing)
    samples = samples_for(ds, cfg, args, "train", timing)
    model = train_model(samples, cfg.features, cfg.segmentation, args.quantile, args.positive_radius_mm / 1e3,
                        args.radius_mm / 1e3, training={"data": args.train or f"rendered train split seed {args.seed}",
                                                        "subjects": sorted(set(ds.subject.tolist())),
                                                        "intrinsics": ds.intrinsics.to_dict()},
                        candidates=Candidates.from_config(cfg.detector, cfg.segmentation))
    path = save_model(model, args.out)
    for name, vm in model.variants.items():
        eer = "-" if vm.train_eer is None else f"{100 * vm.train_eer:.1f} %"
        print(f"{name:<16} operating scale {vm.operating_scale:.3f}  training EER {eer}")
    print(f"wrote {path}")
    return 0
