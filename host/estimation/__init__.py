"""Joint angles from the accelerometers: closed forms (``closed_form``), the EKF (``ekf``),
the fingers' gravity model they share (``finger_gravity``) and the accelerometers' calibration
(``accel_calibration``)."""
