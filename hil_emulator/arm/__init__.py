"""The emulated arm: its MuJoCo model (``model``), plant (``plant``), the steppers' and servos'
actuators (``actuators``) and its nodes on the RS-485 bus (``rig``)."""
