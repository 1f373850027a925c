"""``rt2 labels convert``: a labelled ball data set from one labelling tool's format to another's.

    rt2 labels convert export_from_cvat/ --to coco --out data/my_lab_coco
    rt2 labels convert data/my_lab_coco --to yolo --out out/my_lab_yolo

The output is a data set of its own: the labels, and the images hard-linked (or copied) into
``OUT/images/``. Formats: harness/experiments/detector/labels (README, "Label formats").
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["add_arguments", "run"]


def add_arguments(parser) -> None:
    from harness.experiments.detector.labels import LABEL_FORMATS

    parser.add_argument("src", help="labelled set: a folder or a label file (COCO, YOLO data.yaml, labelme, CVAT XML, Label Studio JSON)")
    parser.add_argument("--to", required=True, choices=tuple(LABEL_FORMATS), help="format to write")
    parser.add_argument("--out", required=True, help="new folder for the converted set (must be absent or empty)")
    parser.add_argument("--label-format", choices=("auto", *LABEL_FORMATS), default="auto", help="format of SRC (default auto: found from the files)")


def run(args) -> int:
    from harness.experiments.detector.labels import detect_format, read_labels, write_labels

    out = Path(args.out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ValueError(f"--out {args.out!r} exists and is not an empty folder; give a new folder")
    src_format = detect_format(args.src) if args.label_format == "auto" else args.label_format
    images = read_labels(args.src, src_format)
    if not images:
        raise ValueError(f"{args.src}: no labelled images")
    written = write_labels(out, images, args.to)
    n_balls = sum(li.n_balls for li in images)
    print(f"read {len(images)} images ({n_balls} balls, {sum(li.n_balls == 0 for li in images)} without a ball) as {src_format} "
          f"from {args.src}; wrote {args.to} to {written}")
    return 0
