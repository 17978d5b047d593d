"""The paper's evaluation: train on TRAIN, per-image ROC and EER of the four detector variants on TEST.

Without --train/--test it renders the default split (train: three subjects at 0.60 m; test: a fourth subject
at 0.35-0.70 m; --train-subjects / --test-subjects render others). With --model it skips training and
evaluates that model. Prints the EER table and what the pipeline would report (the model's operating scale and
the config's margin test: nose found / wrong pixel accepted), overall, per distance and per identity, and writes
DIR/evaluation.json, DIR/roc.png and DIR/model.json.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from tofd.lab.data_args import add_data_arguments

    add_data_arguments(parser, ("train", "test"))
    parser.add_argument("--model", default=None, help="evaluate this model JSON instead of training one")
    parser.add_argument("--out", default="evaluation", metavar="DIR", help="output directory (default ./evaluation)")
    parser.add_argument("--quantile", type=float, default=0.05, help="box quantile q (default 0.05)")
    parser.add_argument("--positive-radius-mm", type=float, default=5.0,
                        help="training pixels: within this 3-D distance of the nose tip (default 5)")


def main(args: argparse.Namespace) -> int:
    import time

    from tofd.algorithm.detector import Candidates, Margin, load_model, save_model
    from tofd.config import load_config
    from tofd.lab.data_args import check_data_arguments, dataset_for, samples_for
    from tofd.lab.evaluation import evaluate_model, train_model
    from tofd.lab.report import answers_table, eer_table, plot_roc, write_json
    from tofd.outputs import check_output_dir, prepare_output_dir

    start = time.monotonic()
    cfg = load_config(args.config)
    check_data_arguments(args, ("train", "test") if args.model is None else ("test",))
    out = check_output_dir(args.out)  # created only once there is something to write
    timing: dict = {}
    radius_m = args.radius_mm / 1e3
    model = None
    if args.model is not None:
        model = load_model(args.model)
        model.check_compatible(cfg.features, cfg.segmentation)
    if args.test is not None:  # a bad test file fails before training, not after
        test = dataset_for(args, "test", timing)
    if model is None:
        train = dataset_for(args, "train", timing)
        samples = samples_for(train, cfg, args, "train", timing)
        model = train_model(samples, cfg.features, cfg.segmentation, args.quantile, args.positive_radius_mm / 1e3,
                            radius_m, training={"data": args.train or f"rendered train split seed {args.seed}",
                                                "subjects": sorted(set(train.subject.tolist()))},
                            candidates=Candidates.from_config(cfg.detector, cfg.segmentation))
        del samples
    if args.test is None:
        test = dataset_for(args, "test", timing)
    samples = samples_for(test, cfg, args, "test", timing)
    sweep = time.monotonic()
    candidates = Candidates.from_config(cfg.detector, cfg.segmentation)
    results = evaluate_model(model, samples, test.distance_m, radius_m, candidates, Margin.from_config(cfg.detector),
                             test.subject)
    timing["roc_sweep_s"] = round(time.monotonic() - sweep, 3)
    timing["total_s"] = round(time.monotonic() - start, 3)

    print(eer_table(results))
    print(answers_table(results))
    print(eer_table(results, per_subject=True))
    print(answers_table(results, per_subject=True))
    prepare_output_dir(out)
    save_model(model, out / "model.json")
    plot_roc(out / "roc.png", results)
    write_json(out / "evaluation.json", results, radius_mm=args.radius_mm, timing=timing,
               test={"data": args.test or f"rendered test split seed {args.seed + 1}", "frames": len(test),
                     "subjects": sorted(set(test.subject.tolist())), "intrinsics": test.intrinsics.to_dict()},
               model=model.to_dict())
    print("timing: " + ", ".join(f"{k} {v}" for k, v in timing.items()))
    print(f"wrote {out / 'evaluation.json'}, {out / 'roc.png'}, {out / 'model.json'}")
    return 0
