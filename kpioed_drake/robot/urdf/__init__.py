"""URDF robots: read a URDF and its sidecar into a robot (:mod:`.read`, the measured joints of a
tree from :mod:`.tree`, the file's numbers checked before Drake reads them by :mod:`.numbers`), and
write a calibrated robot back as URDF plus sidecar (:mod:`.write`, the estimated errors folded into
or out of the joints' placements by :mod:`.origins`)."""

from kpioed_drake.robot.urdf.read import (  # noqa: F401 (the package's entry points)
    MM,
    SidecarSpec,
    UrdfSource,
    add_urdf,
    movable_joints,
    read_urdf_robot,
    sidecar_path,
)
