"""The application: the ``mmsnap`` command line and what it runs (the per-node
pipeline over files, evaluation, the paper's demo, its report and figures).
Everything here may use every layer below; nothing below imports it.
"""
