"""The front end: a frame's camera, depth and grid flow (OpenCV's LK), the keyframes'
tracks and the frames read ahead; what the step's inputs are made from."""
