"""lab's manipulation tasks: arms on MuJoCo Menagerie's models."""
