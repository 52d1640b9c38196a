"""What the stages read and write: params files, stores, outputs, metrics, the pipelines'
file layout. Imports only core."""
