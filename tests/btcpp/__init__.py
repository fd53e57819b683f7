"""BehaviorTree.CPP itself, built from source, as the judge of the XML that ``ktbt convert``
writes: the build (cached outside the clone), a C++ harness and the traces both engines print."""
