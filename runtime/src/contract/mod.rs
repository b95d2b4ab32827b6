//! Contract-Net protocol logic (transport-free).
