"""Heap figures that run.mjs --stepped records before each step of the script's main().

``live`` is gc.mem_alloc() right after the harness's collection between steps: what the script
keeps, without the garbage a step makes. ``steps`` counts the steps started.
"""

live = 0
steps = 0
