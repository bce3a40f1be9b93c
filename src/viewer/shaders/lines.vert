// csb viewer — lines: the ground grid, wireframe (the distance constraints), chains.
#version 330 core

layout(location = 0) in vec3 position;  // world, m
layout(location = 1) in vec4 color;     // sRGB, alpha

uniform mat4 view_projection;
uniform float depth_bias;  // in NDC z, pulls wireframe in front of the surface it lies on

out vec4 v_color;

void main() {
  v_color = color;
  gl_Position = view_projection * vec4(position, 1.0);
  gl_Position.z -= depth_bias * gl_Position.w;
}
