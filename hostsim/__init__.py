"""Host-side tools for tipbot: model, gain design, simulator, fake EV3, replay."""
