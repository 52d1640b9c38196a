"""The paper's method (MimicGen): segments, selection strategies, the generation steps of one
attempt, the batched attempt, pose-estimation noise, support coverage. Imports only core."""
