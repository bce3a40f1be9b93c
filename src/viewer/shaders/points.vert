// csb viewer — particles as round sprites of a fixed size in pixels.
#version 330 core

layout(location = 0) in vec3 position;  // world, m
layout(location = 1) in vec4 color;     // sRGB, alpha

uniform mat4 view_projection;
uniform float point_size;  // pixels

out vec4 v_color;

void main() {
  v_color = color;
  gl_Position = view_projection * vec4(position, 1.0);
  gl_Position.z -= 1e-4 * gl_Position.w;  // drawn over the surface the particle lies on
  gl_PointSize = point_size;
}
