"""The runtime traversal (docs/how-it-works.md#the-runtime; docs/how-it-works.md): which HLOD nodes to draw each frame,
driven by occlusion queries. Draws nothing itself: a renderer (hlod_core.render's, or Blender's
preview) is passed in through the `protocol.NodeRenderer` protocol.

- settings: RuntimeSettings and the values of its mode settings;
- stats: FrameStats, the counters of one frame;
- protocol: NodeRenderer, the query handle, the prediction and query modes;
- metrics, boxes, alpha_estimators: per-frame SSE, bias P_{s,t}, box tests and alpha, vectorised
  over the node table;
- base: the state and helpers every method shares, and `frame(view)`;
- methods: Full, VFC, SW, Ideal, the METHODS table and `methods.make`;
- coherent: the coherent loop and Bool, Simp, Coh;
- query_stream: CHC++'s multiqueries and query batches;
- skipping, query_cost: skipped queries, and the renderer's cost model they read;
- query_gate: no queries at all where they do not pay, and the probes that resume them.
"""
