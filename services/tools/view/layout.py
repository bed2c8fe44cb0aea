"""The Foxglove layout of ``capataz view`` (built with foxglove-sdk's ``foxglove.layouts``): one view of a
UAV's flight. Left: the camera image above the yaw (published, and the truth's when simulated) and the
cluster's per-frame time. Right: the 3D scene (``world`` frame; pose/vo, pose/pf and truth as poses with
their covariance, and ``/tf``) above the raw cluster shares. ``deploy/foxglove/capataz.json`` is
:func:`layout_json` for ``uav0`` (``capataz view --write-layout FILE --uav NAME`` writes another)."""

from __future__ import annotations

import json
from typing import Any


def layout_json(uav: str = "uav0") -> str:
    """The layout as Foxglove's JSON (import it in the app: Layouts, Import from file)."""
    import foxglove.layouts as fl

    base = f"/capataz/uav/{uav}"
    poses: dict[str, Any] = {
        f"{base}/pose/vo/in_frame": fl.BaseRendererPoseTopicSettings(
            visible=True, type="arrow", color="#1f77b4"
        ),
        f"{base}/pose/pf/in_frame": fl.BaseRendererPoseTopicSettings(
            visible=True, type="arrow", color="#d62728"
        ),
        f"{base}/truth/in_frame": fl.BaseRendererPoseTopicSettings(visible=True, type="axis"),
    }
    yaw = fl.PlotPanel(
        title="yaw (rad)",
        config=fl.PlotConfig(
            paths=[
                fl.PlotSeries(value=f"{base}/yaw.yaw_rad", label="published yaw"),
                fl.PlotSeries(value=f"{base}/cluster.timings_ms.total", label="frame time (ms)"),
            ],
            show_legend=True,
        ),
    )
    camera = fl.ImagePanel(
        title="camera", config=fl.ImageConfig(image_mode=fl.ImageModeConfig(image_topic=f"{base}/camera"))
    )
    pose_view = fl.ThreeDeePanel(title="poses", config=fl.ThreeDeeConfig(fixed_frame="world", topics=poses))
    shares = fl.RawMessagesPanel(
        title="cluster shares", config=fl.RawMessagesConfig(topic_path=f"{base}/cluster")
    )

    def column(top: Any, bottom: Any) -> Any:
        """Two panels one above the other, the top one twice as tall."""
        return fl.SplitContainer(
            direction="column",
            items=[fl.SplitItem(proportion=2, content=top), fl.SplitItem(proportion=1, content=bottom)],
        )

    left, right = column(camera, yaw), column(pose_view, shares)
    layout = fl.Layout(
        content=fl.SplitContainer(
            direction="row", items=[fl.SplitItem(content=left), fl.SplitItem(content=right)]
        )
    )
    return json.dumps(json.loads(layout.to_json()), indent=2, sort_keys=True) + "\n"


def layout_topics(layout: dict[str, Any]) -> set[str]:
    """Every topic a layout refers to (paths cut at the first ``.``), for checks against the server."""
    found: set[str] = set()

    def walk(node: Any) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                if isinstance(value, str) and value.startswith("/capataz/"):
                    found.add(value.split(".", 1)[0])
                if isinstance(key, str) and key.startswith("/capataz/"):
                    found.add(key)
                walk(value)
        elif isinstance(node, list):
            for item in node:
                walk(item)

    walk(layout)
    return found
