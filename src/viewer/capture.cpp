#include "viewer/capture.hpp"

#include <png.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <sstream>
#include <csignal>
#include <sys/stat.h>

namespace csb::viewer {

namespace {

double now() {
  using clock = std::chrono::steady_clock;
  return std::chrono::duration<double>(clock::now().time_since_epoch()).count();
}

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

std::string frame_name(const CaptureOptions& o, std::int64_t k) {
  char number[32];
  std::snprintf(number, sizeof number, "%05lld", static_cast<long long>(k));
  return (std::filesystem::path(o.directory) / (o.prefix + "_" + number + ".png")).string();
}

std::string quote(const std::string& s) {  // for /bin/sh
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

}  // namespace

void write_png(const Image& image, const std::string& path) {
  if (image.width <= 0 || image.height <= 0 ||
      image.rgb.size() != static_cast<std::size_t>(image.width) * image.height * 3)
    throw InvalidArgument("write_png: the image is empty or its pixels do not match its size (" + path + ")");
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) throw Error("cannot write " + path + ": " + std::strerror(errno));
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (!png || !info || setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    std::fclose(f);
    throw Error("cannot write " + path + ": libpng failed");
  }
  png_init_io(png, f);
  png_set_IHDR(png, info, static_cast<png_uint_32>(image.width), static_cast<png_uint_32>(image.height), 8,
               PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  for (int y = 0; y < image.height; ++y)
    png_write_row(png, image.rgb.data() + static_cast<std::size_t>(y) * image.width * 3);
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  if (std::fclose(f) != 0) throw Error("cannot write " + path + ": " + std::strerror(errno));
}

std::string find_program(const std::string& name) {
  const char* path = std::getenv("PATH");
  if (!path) return {};
  std::stringstream dirs(path);
  std::string dir;
  while (std::getline(dirs, dir, ':')) {
    if (dir.empty()) continue;
    const std::filesystem::path p = std::filesystem::path(dir) / name;
    struct stat st {};
    if (::stat(p.c_str(), &st) == 0 && S_ISREG(st.st_mode) && (st.st_mode & S_IXUSR)) return p.string();
  }
  return {};
}

CaptureResult capture(Viewer& viewer, const CaptureOptions& o) {
  if (o.frames < 1) throw InvalidArgument("capture: frames must be >= 1, got " + std::to_string(o.frames));
  if (o.every < 1) throw InvalidArgument("capture: every must be >= 1, got " + std::to_string(o.every));
  std::error_code ec;
  std::filesystem::create_directories(o.directory, ec);
  if (ec) throw Error("capture: cannot create the directory " + o.directory + ": " + ec.message());

  CaptureResult result;
  // A video encoder that dies must not take the process with it (SIGPIPE): writes then fail
  // with EPIPE instead, and the previous disposition comes back on return.
  struct IgnorePipe {
    struct sigaction old {};
    IgnorePipe() {
      struct sigaction ignore {};
      ignore.sa_handler = SIG_IGN;
      sigaction(SIGPIPE, &ignore, &old);
    }
    ~IgnorePipe() { sigaction(SIGPIPE, &old, nullptr); }
  } ignore_pipe;
  // The video: raw RGB frames piped into ffmpeg, H.264 in yuv420p (even sizes) for any player.
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> pipe(nullptr, pclose);
  std::string video;
  if (o.video) {
    const std::string ffmpeg = find_program("ffmpeg");
    if (ffmpeg.empty()) {
      result.video_note = "no video: ffmpeg is not on the PATH (apt-get install ffmpeg)";
    } else {
      video = (std::filesystem::path(o.directory) / (o.prefix + ".mp4")).string();
      const Camera& cam = viewer.camera();
      const double fps = 1.0 / (viewer.steps_per_frame() * viewer.dt());
      std::ostringstream cmd;
      cmd << quote(ffmpeg) << " -y -loglevel error -f rawvideo -pix_fmt rgb24 -s " << cam.width << "x" << cam.height
          << " -r " << fps << " -i - -vf 'scale=trunc(iw/2)*2:trunc(ih/2)*2' "
          << "-c:v libx264 -pix_fmt yuv420p -movflags +faststart " << quote(video);
      pipe.reset(popen(cmd.str().c_str(), "w"));
      if (!pipe) {
        result.video_note = "no video: cannot start ffmpeg";
        video.clear();
      }
    }
  }
  std::vector<double> frame_ms, draw_ms;
  for (std::int64_t k = 0; k < o.frames; ++k) {
    const double t0 = now();
    viewer.frame();
    const double t1 = now();
    const Image image = viewer.screenshot();  // waits for the drawing to finish
    const double t2 = now();
    frame_ms.push_back(1e3 * (t2 - t0));
    draw_ms.push_back(1e3 * (t2 - t1) + viewer.stats().last_draw_ms);
    const bool keep = k % o.every == 0 || k == o.frames - 1;
    if (o.png && keep) {
      const std::string path = frame_name(o, k);
      write_png(image, path);
      result.images.push_back(path);
    }
    if (pipe && std::fwrite(image.rgb.data(), 1, image.rgb.size(), pipe.get()) != image.rgb.size()) {
      result.video_note = "no video: ffmpeg stopped reading";
      pipe.reset();
      video.clear();
    }
    if (o.progress) o.progress(k + 1);
  }
  if (pipe) {
    const int status = pclose(pipe.release());
    if (status != 0) {
      result.video_note = "no video: ffmpeg failed (exit status " + std::to_string(status) + ")";
      std::filesystem::remove(video, ec);
      video.clear();
    }
  }
  result.video = video;
  result.ms_per_frame = median(frame_ms);
  result.draw_ms_per_frame = median(draw_ms);
  return result;
}

}  // namespace csb::viewer
