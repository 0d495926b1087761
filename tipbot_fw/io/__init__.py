"""The brick's devices: the interface the loop talks to, the ev3dev implementation, the clock,
the status lights and the speaker. Imports none of the other rooms."""
