"""The model: what is simulated (Scene, its geometry and sampling into particles), its numbers
(Params) and what evolves (State)."""
