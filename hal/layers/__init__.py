"""The HAL's layers: parts of the machine that work with any backend, attached to what it
built (hal/registry.py names them; hal/contract.py is their contract)."""
