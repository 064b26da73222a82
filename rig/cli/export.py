"""`rig export`: a fitted model as a file other programs evaluate; `rig sigma-bag`: a bag with its sigma images
(docs/noise-model.md)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .options import EXIT_UNDETERMINED, refuse_suffix, refuse_unwritable
from .usage import UsageError


def register(sub: argparse._SubParsersAction) -> None:
    from .shared import shared_options, window_options

    p = sub.add_parser("export", parents=[shared_options(), window_options()],
                       help="fit a model and write it as a file other programs evaluate (docs/noise-model.md)")
    p.add_argument("--model", help="the model to fit and export (default: the paper's power law, as rig fit)")
    p.add_argument("-o", "--out", help="the model file to write (default: RECORDING-noise-model.json)")
    p.add_argument("--sigma-map", metavar="Z1,Z2,...", help="also write per-pixel sigma images at these ranges (m): "
                                                            "OUT.sigma-map.npy, .tif (float32) and .png")
    p.add_argument("--test-vectors", action="store_true", help="also write OUT.test-vectors.csv: inputs and the sigma "
                                                               "and standard error there, for a port to check itself")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("sigma-bag", help="copy a recorded bag with a 32FC1 sigma image (m) beside each depth frame, "
                                         "for a ROS pipeline to weight depth by (docs/noise-model.md)")
    p.add_argument("model", metavar="NOISE_MODEL.json", help="the model file rig export wrote")
    p.add_argument("bag", metavar="BAG",
                   help="a RealSense .bag or a ROS 1/ROS 2 bag (.bag, .db3, .mcap, a ROS 2 bag folder)")
    p.add_argument("-o", "--out", help="the bag to write, of the input's kind (default: BAG-sigma.bag for ROS 1, "
                                       "the folder BAG-sigma for ROS 2)")
    p.add_argument("--topic", help="the depth image topic, when the bag has several")
    p.add_argument("--sigma-topic", help="the topic of the sigma images (default: the depth topic + /sigma)")
    p.set_defaults(func=cmd_sigma_bag)


def cmd_export(args: argparse.Namespace) -> int:
    from ..models.parts.prediction import EffectStage
    from ..models.fitting.progress import ProgressCounter
    from ..noise_model import TERMS, NoiseModel
    from ..reports.noise_model_file import default_model_path, model_document, write_model, written_line
    from ..reports.sigma_map import map_problem, parse_ranges, write_sigma_maps
    from .shared import catalogue_of, check_window, fit_or_refuse, model_data, parse_model_option, progress_line

    check_window(args)
    out = Path(args.out) if args.out else default_model_path(args.recording)
    refuse_unwritable(out, "--out")
    refuse_suffix(out, "--out", (".json",), "a noise model (JSON)")
    try:
        ranges = parse_ranges(args.sigma_map) if args.sigma_map is not None else None
    except ValueError as e:
        raise UsageError(str(e)) from None
    model = parse_model_option(args.model, catalogue_of(args)) if args.model else None
    if ranges is not None and model is not None:  # before the work: a map needs inputs per pixel some terms do not have
        unknown = [e.name for e in model.effects if e.stage <= EffectStage.CENSOR and e.name not in TERMS]
        problem = (f"the model has effects rig.noise_model cannot evaluate ({', '.join(unknown)})" if unknown else
                   map_problem([n for e in model.effects if e.stage <= EffectStage.CENSOR for n in TERMS[e.name]]))
        if problem:
            raise UsageError(f"--sigma-map: {problem}")
    with progress_line(args, "rig export") as progress:
        counter = ProgressCounter(progress, 4)
        if model is None:
            from ..analysis import fit_recording

            try:
                r = fit_recording(args.recording, z_min_m=args.z_min, z_max_m=args.z_max, counter=counter)
            except ValueError as e:
                raise UsageError(str(e)) from None
            fit, d, notes = r.fit, r.samples.positive_variance(), r.notes
        else:
            counter.step("reading the recording")
            d, notes = model_data(args.recording, args.z_min, args.z_max)
            counter.step(f"fitting {model.name}")
            fit = fit_or_refuse(model, d)
        counter.step("headline error: where the model is valid")
        doc, h = model_document(fit, d, args.recording, notes)
        counter.finish()
    write_model(doc, out)
    stream = sys.stderr if args.json else sys.stdout
    if args.json:
        print(json.dumps(doc, indent=1))
    print(written_line(doc, out, h), file=stream)
    if ranges is not None:
        written = write_sigma_maps(NoiseModel.from_dict(doc, str(out)), ranges, out.with_name(out.stem + ".sigma-map"))
        print(f"sigma maps: {', '.join(map(str, written))}", file=stream)
    if args.test_vectors:
        from ..reports.port_vectors import ROWS, write_vectors

        vectors = write_vectors(NoiseModel.from_dict(doc, str(out)), out.with_name(out.stem + ".test-vectors.csv"))
        print(f"test vectors: {vectors} ({ROWS} rows)", file=stream)
    if not h.determined:  # written, but said, and the exit status of every command that fitted such a lambda
        print(f"warning: the file is written, but {h.lambda_status.reason}; {h.lambda_status.fix}", file=sys.stderr)
        return EXIT_UNDETERMINED
    return 0


def cmd_sigma_bag(args: argparse.Namespace) -> int:
    from ..noise_model import NoiseModel, NoiseModelError
    from ..reports.sigma_bag import SigmaBagError, default_output, write_sigma_bag

    bag = Path(args.bag)
    out = Path(args.out) if args.out else default_output(bag)
    refuse_unwritable(out, "--out", folder=not out.suffix == ".bag")
    try:
        model = NoiseModel.load(args.model)
        written = write_sigma_bag(model, bag, out, topic=args.topic, sigma_topic=args.sigma_topic)
    except (NoiseModelError, SigmaBagError) as e:
        raise UsageError(str(e)) from None
    for note in written.notes:
        print(f"note: {note}", file=sys.stderr)
    print(f"sigma bag: {written.path} ({written.frames} frames of {written.depth_topic} with their sigma on "
          f"{written.sigma_topic}: {model.doc['model']}, 32FC1, m; depth unit {written.depth_unit_m:g} m; "
          "every other topic copied)")
    return 0
