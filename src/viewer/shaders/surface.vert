// csb viewer — shaded surfaces: cloth, soft bodies and colliders.
#version 330 core

layout(location = 0) in vec3 position;  // world, m
layout(location = 1) in vec3 normal;    // world, area-weighted vertex normal (need not be unit)
layout(location = 2) in vec3 color;     // linear RGB of the front side

uniform mat4 view;             // world -> eye
uniform mat4 view_projection;  // world -> clip

out vec3 v_position;  // eye space
out vec3 v_normal;    // eye space
out vec3 v_color;

void main() {
  v_position = (view * vec4(position, 1.0)).xyz;
  v_normal = mat3(view) * normal;  // the view has no scaling: its rotation part maps normals
  v_color = color;
  gl_Position = view_projection * vec4(position, 1.0);
}
