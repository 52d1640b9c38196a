"""Policies: BC-RNN training and closed-loop evaluation. Imports core, method, data and run."""
