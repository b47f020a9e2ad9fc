"""The executors: what carries out the motion the motor state machines plan.

``base`` is the contract the engine and the motors use; everything else here is behind it.
"""
