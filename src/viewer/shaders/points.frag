#version 330 core

in vec4 v_color;
out vec4 frag_color;

void main() {
  vec2 d = 2.0 * gl_PointCoord - 1.0;
  float r2 = dot(d, d);
  if (r2 > 1.0) discard;
  frag_color = vec4(v_color.rgb * (1.0 - 0.35 * r2), v_color.a);  // a little relief
}
