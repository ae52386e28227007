"""The TASCU's algorithms as plain functions: attitude propagation, servo, motion status, FBC, drift."""
