"""The control cores: raw readings and the battery's voltage -> duties and a log row, no I/O, no
time (the interface and the factory: tipbot_fw.cores.core). Imports nothing of the rooms above
it but tipbot_fw.guard's hardware bounds."""
