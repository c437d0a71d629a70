"""Reading and writing: input meshes (OBJ, PLY, STL, OFF, glTF/GLB, scene specs) as `meshes.TriangleMesh`
(readers: `stl`, `obj` and its `mtl`, `gltf` and `gltf_materials`), the native `.hlod` container
(`hlod_file`), texture images (`textures`), and the procedural scenes that need no input (`procedural`)."""
