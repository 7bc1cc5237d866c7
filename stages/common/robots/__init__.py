"""Robot arms from their URDFs: serial chains, numerical inverse kinematics, collisions."""
