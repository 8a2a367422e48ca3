"""The emulated hand: its MuJoCo model (``model``), the fingers' plant (``finger_plant``), the
sensors' conversions (``sensors``) and its boards wired as on the robot (``rig``)."""
