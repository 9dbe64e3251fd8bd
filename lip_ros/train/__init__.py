"""Training of the LIP networks on synthetic rig data (``lip_train``)."""
