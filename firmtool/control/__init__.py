"""Controllers: LQR/LQG gains, Kalman filters, time-varying edge controllers, stabilisers."""
