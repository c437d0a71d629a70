"""Reading and writing: input meshes (OBJ, PLY, STL, OFF, glTF/GLB, scene specs) as `meshes.TriangleMesh`,
the native `.hlod` container (`hlod_file`), texture images, and the procedural scenes that need no input."""
