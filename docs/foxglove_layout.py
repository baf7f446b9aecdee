"""Write ``docs/foxglove-layout.json``: the Foxglove layout for armvision's recordings and live
view, built with the Foxglove SDK's typed layout classes (``foxglove.layouts``).

3D view in the arm's base frame (the transforms, the tracks as labelled cylinders with their
liquid, the planning scene, the camera image projected from its optical frame), the colour
image, the depth image, the joint angles over time, and the task's status.

    python docs/foxglove_layout.py        # rewrites docs/foxglove-layout.json
"""

from __future__ import annotations

import json
from pathlib import Path

import foxglove.layouts as fl

COLOR = "/camera/color/image_raw/compressed"
DEPTH = "/camera/aligned_depth_to_color/image_raw"
INFO = "/camera/color/camera_info"
JOINTS = ("waist", "shoulder", "elbow", "forearm_roll", "wrist_angle", "wrist_rotate")


def layout() -> fl.Layout:
    three_d = fl.ThreeDeePanel(
        title="bench (vx300s/base_link)",
        config=fl.ThreeDeeConfig(
            follow_tf="vx300s/base_link",
            topics={
                "/armvision/markers": fl.BaseRendererRosMarkerTopicSettings(visible=True),
                "/armvision/planning_scene": fl.BaseRendererRosMarkerTopicSettings(visible=True),
                COLOR: fl.BaseRendererImageTopicSettings(
                    visible=True, camera_info_topic=INFO, distance=0.8
                ),
            },
        ),
    )
    colour = fl.ImagePanel(
        title="colour",
        config=fl.ImageConfig(image_mode=fl.ImageModeConfig(image_topic=COLOR)),
    )
    depth = fl.ImagePanel(
        title="depth (mm)",
        config=fl.ImageConfig(
            image_mode=fl.ImageModeConfig(
                image_topic=DEPTH, color_mode="colormap", color_map="turbo"
            )
        ),
    )
    joints = fl.PlotPanel(
        title="joints (rad)",
        config=fl.PlotConfig(
            paths=[
                fl.PlotSeries(value=f"/vx300s/joint_states.position[{i}]", label=name)
                for i, name in enumerate(JOINTS)
            ],
            show_legend=True,
        ),
    )
    task = fl.RawMessagesPanel(
        title="task", config=fl.RawMessagesConfig(topic_path="/armvision/task")
    )
    right = fl.SplitContainer(
        direction="column",
        items=[
            fl.SplitItem(content=colour),
            fl.SplitItem(content=depth),
            fl.SplitItem(content=joints),
            fl.SplitItem(proportion=0.6, content=task),
        ],
    )
    return fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[fl.SplitItem(proportion=1.6, content=three_d), fl.SplitItem(content=right)],
        )
    )


def main() -> None:
    out = Path(__file__).with_name("foxglove-layout.json")
    out.write_text(json.dumps(json.loads(layout().to_json()), indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
