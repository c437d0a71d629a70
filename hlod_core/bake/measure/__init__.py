"""The bake's error measure (docs/how-it-works.md#the-error): the inner nodes' errors.

Modules: hausdorff, leaf_arrays.
"""
