"""The file layer: every table the package reads, the files a design is written to, format files.

- :mod:`.tables`: the one reader of tables of joint columns and optional columns (CSV text ->
  arrays, with row/column messages); measurement files in two formats of it, the native CSV and a
  layout a format file describes;
- :mod:`.formats`: format files (the layout of another tool's measurement file) and their checks;
- :mod:`.orientations`: orientation conventions (Euler angles of every sequence, intrinsic or
  extrinsic; quaternions, scalar first or last; matrices) -> rotation matrices, and Euler-angle
  sigmas -> sigmas about the tracker axes (pure numpy);
- :mod:`.orientation_columns`: a 6-DoF probe's orientation columns of a measurement file (the
  native ``qw, qx, qy, qz``, a format file's ``orientation`` block) -> ``R_TP``, ``sigma_rot_rad``;
- :mod:`.contacts`: plane-contact and distance files (joint columns, plane / pivot / bar ids
  1-based, lengths) -> checked arrays of :class:`~kpioed_drake.tracker.contactdata.PlaneData` and
  ``DistanceData``, messages naming the file, row and column;
- :mod:`.designs`: design files (read through :mod:`.tables`, written atomically), a measurement
  plan's condition offsets, working poses given as text.

Joint units of files (``q{i}_deg``, prismatic ``q{i}_mm``) are the robot's
(:mod:`kpioed_drake.robot.jointmap`); the :class:`~kpioed_drake.tracker.data.Measurements` type that
a measurement file is read into is the tracker's.
"""
