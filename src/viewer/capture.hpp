// csb viewer — offscreen capture: frames of a viewer written as PNG files, and as an MP4 video
// when ffmpeg is on the PATH.
#pragma once

#include "viewer/viewer.hpp"

#include <functional>
#include <string>
#include <vector>

namespace csb::viewer {

struct CaptureOptions {
  std::int64_t frames = 60;   // frames to draw (each advances the simulation by the viewer's frame_time)
  std::int64_t every = 1;     // write every k-th frame as PNG (the first and the last always); the video has all
  std::string directory = ".";
  std::string prefix = "frame";   // <directory>/<prefix>_<frame number, 5 digits>.png
  bool png = true;
  bool video = true;          // <directory>/<prefix>.mp4 at 1/frame_time frames per second, if ffmpeg is found
  std::function<void(std::int64_t)> progress;  // called with the frames done after each frame (may be empty)
};

struct CaptureResult {
  std::vector<std::string> images;  // written PNG files, in order
  std::string video;                // the MP4 file, or empty
  std::string video_note;           // why there is no video, when there is none
  double ms_per_frame = 0;          // median wall time of a frame (step + draw + read back), over all frames
  double draw_ms_per_frame = 0;     // median wall time of drawing and reading back alone (no step)
};

// Draws `frames` frames of the viewer (in its current state; paused viewers redraw the same
// state) and writes them. Throws csb::Error naming the file that cannot be written.
CaptureResult capture(Viewer& viewer, const CaptureOptions& options);

// The full path of an executable found on the PATH, or empty.
std::string find_program(const std::string& name);

}  // namespace csb::viewer
