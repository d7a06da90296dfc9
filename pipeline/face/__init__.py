"""The face: dlib detection and the 68-point index sets (``dlib_face``), pose geometry, the canonical
frontal frame and surface, face identity, the lower-face mesh."""
