#include "viewer/gl.hpp"

#include "csb/types.hpp"

#include <vector>

namespace csb::viewer {

namespace {

// The info log of a shader or program (get_iv/get_log: glGetShaderiv/glGetShaderInfoLog or the
// program's pair).
template <class GetIv, class GetLog>
std::string info_log(GLuint id, GetIv get_iv, GetLog get_log) {
  GLint n = 0;
  get_iv(id, GL_INFO_LOG_LENGTH, &n);
  std::string log(std::max(n, 1), '\0');
  get_log(id, n, nullptr, log.data());
  return log;
}

GLuint compile(GLenum kind, const std::string& file) {
  const char* source = shader_source(file);
  GLuint s = glCreateShader(kind);
  glShaderSource(s, 1, &source, nullptr);
  glCompileShader(s);
  GLint ok = 0;
  glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    const std::string log = info_log(s, glGetShaderiv, glGetShaderInfoLog);
    glDeleteShader(s);
    throw Error("viewer: shader " + file + " does not compile: " + log);
  }
  return s;
}

}  // namespace

Program::Program(const std::string& vertex_file, const std::string& fragment_file) {
  GLuint vs = compile(GL_VERTEX_SHADER, vertex_file);
  GLuint fs = 0;
  try {
    fs = compile(GL_FRAGMENT_SHADER, fragment_file);
  } catch (...) {
    glDeleteShader(vs);
    throw;
  }
  id_ = glCreateProgram();
  glAttachShader(id_, vs);
  glAttachShader(id_, fs);
  glLinkProgram(id_);
  glDeleteShader(vs);
  glDeleteShader(fs);
  GLint ok = 0;
  glGetProgramiv(id_, GL_LINK_STATUS, &ok);
  if (!ok) {
    const std::string log = info_log(id_, glGetProgramiv, glGetProgramInfoLog);
    glDeleteProgram(id_);
    id_ = 0;
    throw Error("viewer: shaders " + vertex_file + " + " + fragment_file + " do not link: " + log);
  }
}

Program::Program(Program&& other) noexcept : id_(other.id_) { other.id_ = 0; }

Program& Program::operator=(Program&& other) noexcept {
  if (this != &other) {
    if (id_) glDeleteProgram(id_);
    id_ = other.id_;
    other.id_ = 0;
  }
  return *this;
}

Program::~Program() {
  if (id_) glDeleteProgram(id_);
}

Mesh::~Mesh() {
  if (vao_) {
    glDeleteVertexArrays(1, &vao_);
    glDeleteBuffers(4, buffers_);
    if (ebo_) glDeleteBuffers(1, &ebo_);
  }
}

void Mesh::attribute(int k, int components, const float* data, std::size_t vertices, GLenum usage) {
  if (!vao_) {
    glGenVertexArrays(1, &vao_);
    glGenBuffers(4, buffers_);
  }
  glBindVertexArray(vao_);
  glBindBuffer(GL_ARRAY_BUFFER, buffers_[k]);
  const std::size_t bytes = sizeof(float) * components * vertices;
  if (bytes > sizes_[k]) {  // grow, else overwrite in place
    glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(bytes), data, usage);
    sizes_[k] = bytes;
  } else if (bytes > 0) {
    glBufferSubData(GL_ARRAY_BUFFER, 0, static_cast<GLsizeiptr>(bytes), data);
  }
  glEnableVertexAttribArray(k);
  glVertexAttribPointer(k, components, GL_FLOAT, GL_FALSE, 0, nullptr);
  glBindVertexArray(0);
  vertices_ = vertices;
}

void Mesh::update(int k, int components, const float* data, std::size_t first, std::size_t vertices) {
  const std::size_t offset = sizeof(float) * components * first, bytes = sizeof(float) * components * vertices;
  if (!vao_ || bytes == 0 || offset + bytes > sizes_[k]) return;
  glBindBuffer(GL_ARRAY_BUFFER, buffers_[k]);
  glBufferSubData(GL_ARRAY_BUFFER, static_cast<GLintptr>(offset), static_cast<GLsizeiptr>(bytes), data);
  glBindBuffer(GL_ARRAY_BUFFER, 0);
}

void Mesh::share(int k, const Mesh& source, int source_k, int components) {
  if (!vao_) {
    glGenVertexArrays(1, &vao_);
    glGenBuffers(4, buffers_);
  }
  glBindVertexArray(vao_);
  glBindBuffer(GL_ARRAY_BUFFER, source.buffers_[source_k]);
  glEnableVertexAttribArray(k);
  glVertexAttribPointer(k, components, GL_FLOAT, GL_FALSE, 0, nullptr);
  glBindVertexArray(0);
}

void Mesh::indices(const unsigned* data, std::size_t count, GLenum usage) {
  if (!vao_) {
    glGenVertexArrays(1, &vao_);
    glGenBuffers(4, buffers_);
  }
  glBindVertexArray(vao_);
  if (!ebo_) glGenBuffers(1, &ebo_);
  glBindBuffer(GL_ELEMENT_ARRAY_BUFFER, ebo_);
  const std::size_t bytes = sizeof(unsigned) * count;
  if (bytes > ebo_size_) {
    glBufferData(GL_ELEMENT_ARRAY_BUFFER, static_cast<GLsizeiptr>(bytes), data, usage);
    ebo_size_ = bytes;
  } else if (bytes > 0) {
    glBufferSubData(GL_ELEMENT_ARRAY_BUFFER, 0, static_cast<GLsizeiptr>(bytes), data);
  }
  glBindVertexArray(0);
  index_count_ = count;
}

void Mesh::draw(GLenum mode) const {
  if (!vao_) return;
  glBindVertexArray(vao_);
  if (ebo_) {
    if (index_count_) glDrawElements(mode, static_cast<GLsizei>(index_count_), GL_UNSIGNED_INT, nullptr);
  } else if (vertices_) {
    glDrawArrays(mode, 0, static_cast<GLsizei>(vertices_));
  }
  glBindVertexArray(0);
}

void Mesh::draw_range(GLenum mode, std::size_t first, std::size_t count) const {
  if (!vao_ || count == 0 || first + count > vertices_) return;
  glBindVertexArray(vao_);
  glDrawArrays(mode, static_cast<GLint>(first), static_cast<GLsizei>(count));
  glBindVertexArray(0);
}

RenderTarget::~RenderTarget() { release(); }

void RenderTarget::release() {
  if (fbo_) glDeleteFramebuffers(1, &fbo_);
  if (color_) glDeleteRenderbuffers(1, &color_);
  if (depth_) glDeleteRenderbuffers(1, &depth_);
  if (resolve_fbo_) glDeleteFramebuffers(1, &resolve_fbo_);
  if (resolve_color_) glDeleteRenderbuffers(1, &resolve_color_);
  fbo_ = color_ = depth_ = resolve_fbo_ = resolve_color_ = 0;
}

void RenderTarget::resize(int width, int height, int samples) {
  if (width == width_ && height == height_ && samples == samples_ && fbo_) return;
  release();
  width_ = width;
  height_ = height;
  samples_ = samples;
  GLint max_samples = 0;
  glGetIntegerv(GL_MAX_SAMPLES, &max_samples);
  const int s = samples > 1 ? std::min(samples, static_cast<int>(max_samples)) : 0;

  glGenFramebuffers(1, &fbo_);
  glBindFramebuffer(GL_FRAMEBUFFER, fbo_);
  glGenRenderbuffers(1, &color_);
  glBindRenderbuffer(GL_RENDERBUFFER, color_);
  glRenderbufferStorageMultisample(GL_RENDERBUFFER, s, GL_RGBA8, width, height);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, color_);
  glGenRenderbuffers(1, &depth_);
  glBindRenderbuffer(GL_RENDERBUFFER, depth_);
  glRenderbufferStorageMultisample(GL_RENDERBUFFER, s, GL_DEPTH_COMPONENT24, width, height);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, depth_);
  if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
    throw Error("viewer: cannot make a " + std::to_string(width) + "x" + std::to_string(height) +
                " framebuffer with " + std::to_string(s) + " samples");
  if (s > 0) {
    glGenFramebuffers(1, &resolve_fbo_);
    glBindFramebuffer(GL_FRAMEBUFFER, resolve_fbo_);
    glGenRenderbuffers(1, &resolve_color_);
    glBindRenderbuffer(GL_RENDERBUFFER, resolve_color_);
    glRenderbufferStorage(GL_RENDERBUFFER, GL_RGBA8, width, height);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, resolve_color_);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
      throw Error("viewer: cannot make the resolve framebuffer");
  }
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
}

void RenderTarget::bind() const {
  glBindFramebuffer(GL_FRAMEBUFFER, fbo_);
  glViewport(0, 0, width_, height_);
}

void RenderTarget::resolve() const {
  if (!resolve_fbo_) return;
  glBindFramebuffer(GL_READ_FRAMEBUFFER, fbo_);
  glBindFramebuffer(GL_DRAW_FRAMEBUFFER, resolve_fbo_);
  glBlitFramebuffer(0, 0, width_, height_, 0, 0, width_, height_, GL_COLOR_BUFFER_BIT, GL_NEAREST);
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
}

void RenderTarget::read(unsigned char* rgb) const {
  glBindFramebuffer(GL_READ_FRAMEBUFFER, resolve_fbo_ ? resolve_fbo_ : fbo_);
  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  std::vector<unsigned char> flipped(static_cast<std::size_t>(width_) * height_ * 3);
  glReadPixels(0, 0, width_, height_, GL_RGB, GL_UNSIGNED_BYTE, flipped.data());
  glBindFramebuffer(GL_READ_FRAMEBUFFER, 0);
  const std::size_t row = static_cast<std::size_t>(width_) * 3;
  for (int y = 0; y < height_; ++y)  // OpenGL's rows go bottom-up
    std::copy_n(flipped.data() + (height_ - 1 - y) * row, row, rgb + y * row);
}

void RenderTarget::blit_to_window(int window_width, int window_height) const {
  glBindFramebuffer(GL_READ_FRAMEBUFFER, resolve_fbo_ ? resolve_fbo_ : fbo_);
  glBindFramebuffer(GL_DRAW_FRAMEBUFFER, 0);
  glBlitFramebuffer(0, 0, width_, height_, 0, 0, window_width, window_height, GL_COLOR_BUFFER_BIT, GL_LINEAR);
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
}

}  // namespace csb::viewer
