"""The robot model: typed robot and cell data from the model files, kinematics, parameters, geometry.

The one source of truth for geometry: the YAML (DH/Hayati) or URDF robot files and the cell file are
loaded into typed dataclasses (:mod:`.models`, schemas in :mod:`.modelspec`), from which both the numpy
kinematics (:mod:`.kinematics`, :mod:`.chain`) and the Drake MultibodyPlant (:mod:`.plant`) are built.
"""
