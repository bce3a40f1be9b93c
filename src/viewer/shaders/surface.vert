// csb viewer — shaded surfaces: cloth, soft bodies and colliders.
#version 330 core

layout(location = 0) in vec3 position;  // the object's frame, m
layout(location = 1) in vec3 normal;    // the object's frame, area-weighted vertex normal (need not be unit)
layout(location = 2) in vec3 color;     // linear RGB of the front side

uniform mat4 model;            // object -> world: a rigid pose (a collider's), the identity for the cloth
uniform mat4 view;             // world -> eye
uniform mat4 view_projection;  // world -> clip

out vec3 v_position;  // eye space
out vec3 v_normal;    // eye space
out vec3 v_color;

void main() {
  vec4 world = model * vec4(position, 1.0);
  v_position = (view * world).xyz;
  v_normal = mat3(view) * (mat3(model) * normal);  // neither scales: their rotations map normals
  v_color = color;
  gl_Position = view_projection * world;
}
