"""The robot model: typed robot and cell data from the model files, kinematics, parameters, geometry.

The one source of truth for geometry: the YAML (DH/Hayati) or URDF robot files and the cell file are
loaded into typed dataclasses (:mod:`.models`, the cell in :mod:`.cell`, schemas in :mod:`.modelspec`),
from which both the numpy kinematics (:mod:`.kinematics`, :mod:`.chain`) and the Drake MultibodyPlant
(:mod:`.plant`) are built. :mod:`.reference`: the geometry a calibrated extended model's effects are
evaluated on (the model its fit started from), so that the file predicts what the fit predicted.
:mod:`.jointmap`: controller angles to model angles; :mod:`.drivetrain`: drive types and the
coupling pairs of the structure; :mod:`.urdf`: URDF robots; :mod:`.geometry`: capsule clearances.
"""
