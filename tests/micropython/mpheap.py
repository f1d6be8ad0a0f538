"""Heap figures that run.mjs --stepped records before each step of the script's main().

``live`` is gc.mem_alloc() right after the harness's collection between steps: what the script
keeps, without the garbage a step makes. ``peak`` is the highest gc.mem_alloc() at the end of a
step so far, before the collection: live heap plus the step's garbage, the most heap the run has
needed, which --heap must cover. ``high`` is that gc.mem_alloc() for the last step alone. ``steps``
counts the steps started.
"""

live = 0
peak = 0
high = 0
steps = 0
