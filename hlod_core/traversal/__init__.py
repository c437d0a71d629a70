"""The runtime traversal (docs/how-it-works.md): per-frame box tests and screen-space errors
vectorised over the node table, the bias P_{s,t}, the query cost model, the alpha estimators, and the
traversal methods (Full, VFC, Bool, SW, Simp, Coh, Ideal) behind one `frame(view)` entry point.
Draws nothing itself: a renderer (hlod_core.render or Blender's) is passed in."""
