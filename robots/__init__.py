"""Robot MJCF models shipped with cfm_jax (installed as the data package cfm_jax._robot_files)."""
