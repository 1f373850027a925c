"""CVAT for images 1.1 (XML), as CVAT exports it (a zip of ``annotations.xml`` and ``images/``)::

    <annotations>
      <version>1.1</version>
      <meta><task><labels><label><name>ball</name>...</label></labels></task></meta>
      <image id="0" name="frame_000123.png" width="640" height="480">
        <box label="ball" source="manual" occluded="0" xtl="311.2" ytl="202.9" xbr="319.4" ybr="211.0" z_order="0"/>
        <ellipse label="ball" cx="315.3" cy="207.0" rx="4.1" ry="4.0" .../>
      </image>
    </annotations>

Coordinates are pixels (continuous, as COCO's). A ``ball`` may be a ``box``, an ``ellipse`` or a
``polygon`` (its bounding box; ``points="x1,y1;x2,y2;..."``); ``points`` and ``polyline`` have no size
and are refused. Image ``name`` is looked for beside the XML, then in its ``images/`` folder. CVAT's
video export (``<track>`` elements) is refused with the way out: export as "CVAT for images 1.1".
CVAT's "COCO 1.0" export (``annotations/instances_default.json`` and ``images/``) is COCO and read
as such (:mod:`harness.experiments.detector.labels`).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from xml.sax.saxutils import quoteattr

from checks.files import MAX_DATA_BYTES, read_bytes_capped, short
from harness.experiments.detector.labels.common import LabelError, box_inside, find_image, is_ball, labelled, number

__all__ = ["ANNOTATIONS_XML", "read_cvat", "write_cvat"]

ANNOTATIONS_XML = "annotations.xml"


def read_cvat(path) -> list:
    """Ball labels from a CVAT for images 1.1 XML file, or a folder holding ``annotations.xml``."""
    path = Path(path)
    xml = path / ANNOTATIONS_XML if path.is_dir() else path
    src = str(xml)
    data = read_bytes_capped(xml, MAX_DATA_BYTES, "CVAT XML file")
    if b"<!DOCTYPE" in data or b"<!ENTITY" in data:
        raise LabelError(f"{src}: XML with a DOCTYPE or entities is refused (CVAT never writes them)")
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise LabelError(f"{src}: not valid XML: {exc}") from None
    if root.tag != "annotations":
        raise LabelError(f"{src}: expected the root element <annotations> (CVAT for images 1.1), got <{short(root.tag)}>")
    if root.find("track") is not None and root.find("image") is None:
        raise LabelError(f"{src}: element <track>: this is CVAT's video export; export the task as 'CVAT for images 1.1'")
    labels = [e.text for e in root.iterfind("meta/*/labels/label/name")]
    if labels and not any(is_ball(n) for n in labels):
        raise LabelError(f"{src}: element <labels> has no 'ball' label; labels present: {short(labels)}")
    out = []
    for i, im in enumerate(root.iterfind("image")):
        where = f"{src}: <image> {i} (id {short(im.get('id'))})"
        for key in ("name", "width", "height"):
            if im.get(key) in (None, ""):
                raise LabelError(f"{where}: missing attribute {key!r}")
        size = []
        for key in ("width", "height"):
            v = im.get(key)
            if not v.isdigit() or int(v) <= 0:
                raise LabelError(f"{where}: attribute {key!r} must be a positive integer, got {short(v)}")
            size.append(int(v))
        width, height = size
        image = find_image(im.get("name"), [xml.parent, xml.parent / "images"], where, "name")
        boxes = []
        for shape in im:
            if not is_ball(shape.get("label")):
                continue
            boxes.append(_shape_box(shape, f"{where} <{shape.tag}>", width, height))
        out.append(labelled(image, width, height, boxes))
    if not out:
        raise LabelError(f"{src}: no <image> elements (CVAT for images 1.1 lists one per image)")
    return out


def _attrs(el, keys, where) -> list[float]:
    vals = []
    for k in keys:
        if el.get(k) is None:
            raise LabelError(f"{where}: missing attribute {k!r}")
        vals.append(number(el.get(k), where, k))
    return vals


def _shape_box(el, where: str, width: int, height: int) -> list[float]:
    if el.tag == "box":
        if number(el.get("rotation") or "0", where, "rotation") != 0:
            raise LabelError(f"{where}: attribute 'rotation' {short(el.get('rotation'))}: rotated boxes are not supported; draw the ball's box unrotated")
        xtl, ytl, xbr, ybr = _attrs(el, ("xtl", "ytl", "xbr", "ybr"), where)
        return box_inside(xtl, ytl, xbr - xtl, ybr - ytl, width, height, where, "xtl/ytl/xbr/ybr")
    if el.tag == "ellipse":
        cx, cy, rx, ry = _attrs(el, ("cx", "cy", "rx", "ry"), where)
        return box_inside(cx - rx, cy - ry, 2 * rx, 2 * ry, width, height, where, "cx/cy/rx/ry")
    if el.tag == "polygon":
        raw = el.get("points") or ""
        try:
            pts = [tuple(float(v) for v in p.split(",")) for p in raw.split(";") if p.strip()]
        except ValueError:
            pts = []
        if len(pts) < 3 or any(len(p) != 2 for p in pts):
            raise LabelError(f"{where}: attribute 'points' must be at least 3 points 'x,y;x,y;...', got {short(raw)}")
        xs, ys = [p[0] for p in pts], [p[1] for p in pts]
        return box_inside(min(xs), min(ys), max(xs) - min(xs), max(ys) - min(ys), width, height, where, "points")
    raise LabelError(f"{where}: a <{el.tag[:40]}> cannot label a ball (it has no size); use a box, an ellipse or a polygon")


def write_cvat(out_dir, images) -> Path:
    """``out_dir/annotations.xml`` (CVAT for images 1.1) for ``images`` placed under ``out_dir/images/``."""
    from harness.common.outputs import atomic_write_text

    out_dir = Path(out_dir)
    base = (out_dir / "images").resolve()
    lines = ['<?xml version="1.0" encoding="utf-8"?>', "<annotations>", "  <version>1.1</version>",
             "  <meta><task><name>rt2 ball labels</name><size>%d</size><mode>annotation</mode>" % len(images),
             "    <labels><label><name>ball</name><type>any</type><attributes/></label></labels></task></meta>"]
    for i, li in enumerate(images):
        name = Path(li.path).resolve().relative_to(base).as_posix()
        lines.append(f'  <image id="{i}" name={quoteattr(name)} width="{li.width}" height="{li.height}">')
        for x, y, w, h in li.boxes_xywh.tolist():
            lines.append(f'    <box label="ball" source="manual" occluded="0" xtl="{x!r}" ytl="{y!r}" xbr="{x + w!r}" ybr="{y + h!r}" z_order="0"/>')
        lines.append("  </image>")
    lines.append("</annotations>")
    return atomic_write_text(out_dir / ANNOTATIONS_XML, "\n".join(lines) + "\n", "annotations.xml")
