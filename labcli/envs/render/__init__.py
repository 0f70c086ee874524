"""Looking at env 0: the OpenGL backend choice, offscreen images, mp4 videos, MuJoCo's viewer."""
