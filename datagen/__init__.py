"""datagen: NLOS SPAD lidar simulation (Scholes & Leach, Sensors 2024) and dataset generation."""
