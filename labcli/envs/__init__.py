"""The batched env and what it is made of: the task API (`TaskSpec`, `Task`), the simulation
backends (`sim/`), the CUDA-graphed step, wrappers, the gymnasium bridge and rendering."""
