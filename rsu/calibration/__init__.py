"""Camera commissioning: the camera model in OpenCV's terms (``camera_geometry``), the pose solved from surveyed
points (``solve``), the localisation error to expect from it (``error``) and the check image (``overlay``)."""
