"""The daemon's controller service closing the loop over a simulated board, in simulated time."""
