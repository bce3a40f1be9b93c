// csb viewer — thin RAII over the OpenGL 3.3 core objects the viewer uses. Functions come from
// libepoxy, which resolves them for whatever context is current (GLX window or EGL offscreen).
#pragma once

#include <epoxy/gl.h>

#include <string>

namespace csb::viewer {

// GLSL sources compiled into the library from src/viewer/shaders/ (see shaders.cpp.in).
const char* shader_source(const std::string& file);

class Program {
 public:
  Program() = default;
  // Compiles and links; throws csb::Error with the GLSL log and the file names on failure.
  Program(const std::string& vertex_file, const std::string& fragment_file);
  Program(Program&& other) noexcept;
  Program& operator=(Program&& other) noexcept;
  Program(const Program&) = delete;
  Program& operator=(const Program&) = delete;
  ~Program();

  void use() const { glUseProgram(id_); }
  GLint uniform(const char* name) const { return glGetUniformLocation(id_, name); }
  GLuint id() const { return id_; }

 private:
  GLuint id_ = 0;
};

// A vertex array with its own buffers: attribute k reads buffer k, tightly packed floats.
class Mesh {
 public:
  Mesh() = default;
  Mesh(const Mesh&) = delete;
  Mesh& operator=(const Mesh&) = delete;
  ~Mesh();

  // Creates the vertex array on first use; `components` floats per vertex in attribute k.
  void attribute(int k, int components, const float* data, std::size_t vertices, GLenum usage = GL_DYNAMIC_DRAW);
  // Attribute k reads buffer `source_k` of `source` (shared, not copied), so that data several
  // vertex arrays draw, such as the particles' positions, is uploaded once. `source` must have
  // had that attribute set and must outlive this mesh's draws.
  void share(int k, const Mesh& source, int source_k, int components);
  // Overwrites vertices [first, first + vertices) of attribute k in place (set by attribute()
  // before, at least that long): one deforming collider's range of the colliders' soup.
  void update(int k, int components, const float* data, std::size_t first, std::size_t vertices);
  void indices(const unsigned* data, std::size_t count, GLenum usage = GL_STATIC_DRAW);
  void draw(GLenum mode) const;  // indexed if indices were given, else all vertices
  // Vertices [first, first + count) without indices (one collider of the colliders' soup).
  void draw_range(GLenum mode, std::size_t first, std::size_t count) const;
  std::size_t vertices() const { return vertices_; }
  std::size_t index_count() const { return index_count_; }

 private:
  GLuint vao_ = 0;
  GLuint buffers_[4] = {0, 0, 0, 0};
  std::size_t sizes_[4] = {0, 0, 0, 0};  // bytes allocated in each buffer
  GLuint ebo_ = 0;
  std::size_t ebo_size_ = 0;
  std::size_t vertices_ = 0, index_count_ = 0;
};

// Where the viewer draws: a multisampled colour + depth target resolved into a plain one, whose
// pixels screenshots read and which a window blits to its own framebuffer.
class RenderTarget {
 public:
  RenderTarget() = default;
  RenderTarget(const RenderTarget&) = delete;
  RenderTarget& operator=(const RenderTarget&) = delete;
  ~RenderTarget();

  // (Re)allocates for this size; samples <= 1: no multisampling.
  void resize(int width, int height, int samples);
  void bind() const;     // draw into the multisampled target
  void resolve() const;  // multisampled -> resolved
  // RGB8 pixels of the resolved image, top row first.
  void read(unsigned char* rgb) const;
  // Copies the resolved image into the current window's framebuffer.
  void blit_to_window(int window_width, int window_height) const;
  int width() const { return width_; }
  int height() const { return height_; }

 private:
  void release();
  int width_ = 0, height_ = 0, samples_ = 0;
  GLuint fbo_ = 0, color_ = 0, depth_ = 0;             // multisampled (or the only one)
  GLuint resolve_fbo_ = 0, resolve_color_ = 0;         // when multisampled
};

}  // namespace csb::viewer
