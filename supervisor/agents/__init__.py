"""The decentralized agents over Zenoh: messages, peers, liveness, the ground station."""
