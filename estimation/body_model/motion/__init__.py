"""Motion library and pose prior of the body model: seeded, plausible θ and τ sequences.

No motion-capture database ships in any package we can use, so motion is generated:
smooth random trajectories plus scripted actions, within the joint limits
(``docs/motion-prior.md``). The synthetic studio renders these motions and
discriminative training draws its poses from the same prior. Modules, lowest first:

- ``seeds``: disjoint seed ranges for training, test and demo draws;
- ``rest``: the body facts motion needs (rest joints, soles, named poses), the
  left-right mirror and the default joint limits;
- ``signals``: smooth signal primitives (minimum jerk, random sinusoids, soft clip);
- ``ik``: key-pose construction (pointing an arm, sagittal legs, the neutral stance);
- ``contact``: feet on the floor (:func:`~.contact.place_root`) and arms clear of
  head and chest (:func:`~.contact.arm_intrusion`);
- ``clips``: the body-relative clip generators and the plausibility bounds;
- ``library``: ``Motion``, the named generators ``MOTIONS``, ``make_motion`` and
  ``ground_motion``;
- ``prior``: independent pose draws for training sets (``sample_pose_prior``).

Everything but :func:`~.library.ground_motion` is numpy-only (plus the numpy-only
``skeleton`` and ``rotations`` modules) and never loads the body model.
"""
