"""The data the rest of the core works on: the HLOD node table (`hierarchy`), materials and vertex
attribute layouts (`appearance`), a camera for one frame (`view`) and camera paths (`camera_path`)."""
