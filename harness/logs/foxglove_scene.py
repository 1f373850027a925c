"""What Foxglove / Lichtblick draw in their 3D panel: the table, cameras, arm and balls as foxglove.SceneUpdate.

All geometry is in the lab world frame (metres; x along the table towards the opponent, z up;
table top at z = 0.76 m). Builders return serialized protobuf messages; the writer picks topics.
"""

from __future__ import annotations

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.SceneEntityDeletion_pb2 import SceneEntityDeletion
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from harness.logs.codecs import timestamp
from harness.logs.topics import WORLD_FRAME
from policies.ball_model import TableGeometry

__all__ = ["TABLE", "scene_static", "scene_arm", "scene_balls", "camera_calibration", "tracker_color"]

#: table-tennis table and net in the lab world frame (their one definition: TableGeometry's defaults)
TABLE = TableGeometry()
_PALETTE = [(0.90, 0.30, 0.10), (0.10, 0.60, 0.95), (0.20, 0.80, 0.30), (0.85, 0.20, 0.80), (0.95, 0.80, 0.10)]


def tracker_color(index: int) -> tuple[float, float, float]:
    return _PALETTE[index % len(_PALETTE)]


def _color(c, rgb, a=1.0):
    c.r, c.g, c.b, c.a = rgb[0], rgb[1], rgb[2], a


def _pose(p, xyz=(0.0, 0.0, 0.0)):
    p.position.x, p.position.y, p.position.z = (float(v) for v in xyz)
    p.orientation.w = 1.0


def _entity(update: SceneUpdate, log_time_ns: int, entity_id: str):
    e = update.entities.add(frame_id=WORLD_FRAME, id=entity_id)
    e.timestamp.CopyFrom(timestamp(log_time_ns))
    return e


def _cube(e, center, size, rgb, a=1.0):
    c = e.cubes.add()
    _pose(c.pose, center)
    c.size.x, c.size.y, c.size.z = size
    _color(c.color, rgb, a)


def _lines(e, X_world: np.ndarray, rgb, thickness: float, kind=LinePrimitive.LINE_LIST, scale_invariant=True):
    ln = e.lines.add(type=kind, thickness=thickness, scale_invariant=scale_invariant)
    _pose(ln.pose)
    for x, y, z in np.asarray(X_world, float).tolist():
        ln.points.add(x=x, y=y, z=z)
    _color(ln.color, rgb)


def _spheres(e, X_world: np.ndarray, diameter_m: float, rgb, a=1.0):
    for xyz in np.asarray(X_world, float).reshape(-1, 3).tolist():
        s = e.spheres.add()
        _pose(s.pose, xyz)
        s.size.x = s.size.y = s.size.z = diameter_m
        _color(s.color, rgb, a)


def _frustum_points(cam, depth_m: float) -> np.ndarray:
    """(16, 3) LINE_LIST points: centre -> 4 image corners at ``depth_m``, and the corner rectangle."""
    w, h = cam.image_size
    corners_px = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    rays = cam.rays_world(corners_px)  # (4, 3) unit directions, world frame
    axis = cam.R_world_to_cam[2]  # optical axis in the world frame
    corners = cam.center_world + depth_m * rays / (rays @ axis)[:, None]
    c = np.repeat(cam.center_world[None], 4, axis=0)
    rect = np.stack([corners, np.roll(corners, -1, axis=0)], axis=1).reshape(-1, 3)
    return np.concatenate([np.stack([c, corners], axis=1).reshape(-1, 3), rect])


def scene_static(log_time_ns: int, rig=None, *, frustum_depth_m: float = 0.4) -> bytes:
    """Table top, white lines, net and (with a rig) each camera's frustum and name."""
    t = TABLE
    up = SceneUpdate()
    e = _entity(up, log_time_ns, "table")
    centre_xy = ((t.x_min_m + t.x_max_m) / 2, (t.y_min_m + t.y_max_m) / 2)
    _cube(e, (*centre_xy, t.surface_z_m - t.thickness_m / 2), (t.x_max_m - t.x_min_m, t.y_max_m - t.y_min_m, t.thickness_m),
          (0.05, 0.15, 0.45))
    x0, x1, y0, y1, z = t.x_min_m, t.x_max_m, t.y_min_m, t.y_max_m, t.surface_z_m + 1e-3
    edges = [(x0, y0), (x1, y0), (x1, y0), (x1, y1), (x1, y1), (x0, y1), (x0, y1), (x0, y0), (x0, centre_xy[1]), (x1, centre_xy[1])]
    _lines(e, [(x, y, z) for x, y in edges], (1.0, 1.0, 1.0), 2.0)
    net = _entity(up, log_time_ns, "net")
    _cube(net, (0.0, 0.0, t.surface_z_m + t.net_height_m / 2), (0.005, 2 * t.net_half_span_m, t.net_height_m),
          (0.95, 0.95, 0.95), 0.6)
    for cam in (rig or ()):
        ce = _entity(up, log_time_ns, f"camera/{cam.name}")
        _lines(ce, _frustum_points(cam, frustum_depth_m), (0.9, 0.9, 0.2), 1.5)
        txt = ce.texts.add(billboard=True, font_size=14.0, scale_invariant=True, text=cam.name)
        _pose(txt.pose, cam.center_world + np.array([0.0, 0.0, 0.08]))
        _color(txt.color, (0.9, 0.9, 0.2))
    return up.SerializeToString()


def scene_arm(log_time_ns: int, X_world: np.ndarray, *, link_diameter_m: float = 0.08) -> bytes:
    """The arm as a line strip through the link-frame origins X_world (n, 3), joints as spheres."""
    up = SceneUpdate()
    e = _entity(up, log_time_ns, "arm")
    _lines(e, X_world, (0.7, 0.7, 0.75), link_diameter_m, kind=LinePrimitive.LINE_STRIP, scale_invariant=False)
    _spheres(e, X_world, 1.2 * link_diameter_m, (0.3, 0.3, 0.35))
    return up.SerializeToString()


def scene_balls(log_time_ns: int, true_ball_m, tracked: list, *, diameter_m: float = 0.04) -> bytes:
    """Spheres: the true ball (white, if given) and each tracker's ball; tracked = [(name, (3,) or None)].

    A tracker that reports no position has its sphere deleted, so a stale ball is never shown.
    """
    up = SceneUpdate()
    ts = timestamp(log_time_ns)

    def put(entity_id, position, rgb, alpha):
        if position is None:
            up.deletions.add(type=SceneEntityDeletion.MATCHING_ID, id=entity_id).timestamp.CopyFrom(ts)
        else:
            _spheres(_entity(up, log_time_ns, entity_id), position, diameter_m, rgb, alpha)

    put("ball/true", true_ball_m, (1.0, 1.0, 1.0), 0.5)
    for i, (name, position) in enumerate(tracked):
        put(f"ball/{name}", position, tracker_color(i), 1.0)
    return up.SerializeToString()


def camera_calibration(log_time_ns: int, cam) -> bytes:
    """foxglove.CameraCalibration of a tracker.Camera (frame_id = camera name; OpenCV conventions)."""
    K = cam.K
    P = np.hstack([K, np.zeros((3, 1))])
    model = "rational_polynomial" if cam.distortion_model == "rational_polynomial" else "plumb_bob"
    D = cam.dist8 if model == "rational_polynomial" else cam.dist8[:5]
    w, h = cam.image_size
    msg = CameraCalibration(frame_id=cam.name, width=int(w), height=int(h), distortion_model=model,
                            D=D.tolist(), K=K.ravel().tolist(), R=np.eye(3).ravel().tolist(), P=P.ravel().tolist())
    msg.timestamp.CopyFrom(timestamp(log_time_ns))
    return msg.SerializeToString()
