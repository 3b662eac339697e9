"""What the identification workflows share; `gear`, `calibration` and `diagnosis` import this package,
never each other.

- `_parameters`: parameter maps (`ParameterMap`, names such as `a3`, `u0_5`, `tool_x`), the robot with
  them applied, and the marker model of a pose at its gravity deflection (`predict_pose`, thesis 3.2.3).
- `_identifiability`, `_observability`, `_pose_selection`, `_task_design`: which parameters the poses identify
  (QR pivoting of the scaled Jacobian), observability indices, random feasible poses and DETMAX, and the poses
  that minimise a task's predicted error (`task_poses`).
- `_batched_lm`: Levenberg-Marquardt on a batch of independent problems (fleets, candidate fits).
- `_noise`, `_robust`, `_pose_checks`: the tracker's noise model and chi-square test, robust losses
  (IRLS weights, outliers), and the unit and consistency checks of pose measurements.

The discrepancy workflow's own chain (rest pose with backlash, compliance and approach-dependent gear
sets, `identification.diagnosis._model`) is a layout of effects on top of these parameters.
"""
