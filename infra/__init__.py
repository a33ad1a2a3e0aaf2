"""skynav.infra: the house's infrastructure, which every room may import and which imports none.

skynav's own error class (:mod:`.errors`), the environment variables that hold a count
(:mod:`.environment`: ``SKYNAV_THREADS`` in :mod:`.threads`, ``SKYNAV_MAX_COUNT`` in
:mod:`.count_cap`), where the installed data files live (:mod:`.data_files`), atomic file writes
and checksums (:mod:`.atomic_files`), the one process pool (:mod:`.pool`) and the heap of a
process that makes many frames (:mod:`.heap`). Nothing here knows about skies, images or
navigation; importing the package loads none of its modules.
"""
