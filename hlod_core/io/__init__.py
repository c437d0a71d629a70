"""Reading and writing: input meshes (OBJ, PLY, STL, OFF, glTF/GLB, scene specs) as `meshes.TriangleMesh`
(readers: `stl`, `obj` and its `mtl`, `text_numbers` for both, `gltf` with `gltf_accessors`,
`gltf_materials` and the glTF codes `gltf_codes`), the native `.hlod` container (`hlod_file`), texture images
(`textures`) and the folder a bake writes the images it makes into (`texture_folder`), and the procedural scenes that
need no input (`procedural`)."""
