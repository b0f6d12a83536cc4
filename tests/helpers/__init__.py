"""Plain helpers the tests share where a fixture cannot serve (constants, classes, assertions)."""
