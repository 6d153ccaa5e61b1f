"""Host code: frames and files, OpenCV's grid flow, masks and overlays, threads that
read ahead and write behind, the compile cache, the OpenCV peers."""
