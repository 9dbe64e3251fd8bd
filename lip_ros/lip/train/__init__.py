"""Training of the LIP networks on synthetic rig data (the ``lip_train`` tool drives it)."""
