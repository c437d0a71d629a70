"""The bake's run: where its tasks run (this process, worker processes, a Dask cluster), the cache of what
earlier bakes made, and a bake in a child process.

Modules: cache, cache_files, cache_keys, cache_proxies, child, dask_cluster, lod_spill, schedule, tasks, workers.
"""
