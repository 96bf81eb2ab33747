"""Bodies: Pinocchio models (URDF or the anthropometric human, seated or standing), their capsules, environment,
skeleton and mirror."""
