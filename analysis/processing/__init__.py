"""Signal processing: filtering and differentiation, parallel decimation, the observation system, period averaging."""
