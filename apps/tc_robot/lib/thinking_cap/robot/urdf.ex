defmodule ThinkingCap.Robot.URDF do
  @moduledoc """
  Reads a robot's geometry from a ROS URDF file: its links (with their
  visual and collision geometry) and the joints between them, so that an
  RDF can take sensor poses (`link:`) and wheel geometry from the URDF the
  robot already has.

      {:ok, urdf} = URDF.load("turtlebot3_burger.urdf")
      {:ok, {x, y, z, roll, pitch, yaw}} = URDF.pose(urdf, "base_scan")
      {:ok, %{separation: 0.16, radius: 0.033}} = URDF.wheels(urdf)

  What is read: `<link>` elements with their `<visual>` and `<collision>`
  geometry (`cylinder` radius and length, `box` size, `sphere` radius,
  `mesh` file name and scale, each with its `<origin>`), and `<joint>`
  elements with their type, parent and child links, `<origin xyz rpy>`
  (defaults 0) and `<axis xyz>` (default `1 0 0`). Everything else
  (materials, inertia, transmissions, Gazebo tags) is ignored. Xacro is not
  expanded: give a URDF produced by `xacro`.

  Poses are of the links' frames at joint position 0 (the URDF's own
  convention), in metres and radians; `rpy` is roll, pitch, yaw about the
  fixed x, y, z axes (`R = Rz(yaw) Ry(pitch) Rx(roll)`).

  The file is parsed with `:xmerl_sax_parser`, so element and attribute
  names stay strings: a URDF cannot fill the atom table.
  """

  defstruct [:file, :name, links: %{}, joints: %{}]

  @typedoc "`{{x, y, z}, {roll, pitch, yaw}}`, metres and radians."
  @type origin :: {{float(), float(), float()}, {float(), float(), float()}}

  @type geometry ::
          %{type: :cylinder, radius: float(), length: float(), origin: origin()}
          | %{type: :box, size: {float(), float(), float()}, origin: origin()}
          | %{type: :sphere, radius: float(), origin: origin()}
          | %{
              type: :mesh,
              filename: String.t(),
              scale: {float(), float(), float()},
              origin: origin()
            }

  @type link :: %{name: String.t(), visual: [geometry()], collision: [geometry()]}

  @type joint_type :: :revolute | :continuous | :prismatic | :fixed | :floating | :planar

  @type joint :: %{
          name: String.t(),
          type: joint_type(),
          parent: String.t(),
          child: String.t(),
          origin: origin(),
          axis: {float(), float(), float()}
        }

  @type t :: %__MODULE__{
          file: Path.t(),
          name: String.t(),
          links: %{String.t() => link()},
          joints: %{String.t() => joint()}
        }

  @typedoc "A 3-D pose: position (m) and roll, pitch, yaw (rad)."
  @type pose6 :: {float(), float(), float(), float(), float(), float()}

  @joint_types %{
    "revolute" => :revolute,
    "continuous" => :continuous,
    "prismatic" => :prismatic,
    "fixed" => :fixed,
    "floating" => :floating,
    "planar" => :planar
  }

  @zero_origin {{0.0, 0.0, 0.0}, {0.0, 0.0, 0.0}}

  ## Loading

  @doc """
  Reads and checks a URDF file. Errors name the file and the problem: a
  missing file, malformed XML (with its line), a root element that is not
  `<robot>`, a link or joint without a name, a joint of an unknown type or
  without parent or child, a joint naming an unknown link, a link with two
  parents, numbers that do not parse.
  """
  @spec load(Path.t()) :: {:ok, t()} | {:error, String.t()}
  def load(path) do
    with {:ok, xml} <- read(path),
         {:ok, root} <- parse(xml, path),
         {:ok, urdf} <- build(root, path) do
      check_tree(urdf)
    end
  end

  defp read(path) do
    case File.read(path) do
      {:ok, xml} -> {:ok, xml}
      {:error, reason} -> {:error, "#{path}: cannot read the URDF: #{:file.format_error(reason)}"}
    end
  end

  # A tree of {name, %{attribute => value}, [children]}, strings throughout.
  defp parse(xml, path) do
    handler = fn
      {:startElement, _uri, name, _qname, attributes}, _loc, stack ->
        attrs = Map.new(attributes, fn {_uri, _prefix, k, v} -> {to_string(k), to_string(v)} end)
        [{to_string(name), attrs, []} | stack]

      {:endElement, _uri, _name, _qname}, _loc, [element, {n, a, children} | stack] ->
        [{n, a, [reverse_children(element) | children]} | stack]

      {:endElement, _uri, _name, _qname}, _loc, [element] ->
        [{:done, reverse_children(element)}]

      _event, _loc, stack ->
        stack
    end

    case :xmerl_sax_parser.stream(xml, event_fun: handler, event_state: []) do
      {:ok, [{:done, root}], rest} ->
        # the parser stops at the root's end: comments and processing
        # instructions may follow it, nothing else
        trailing = Regex.replace(~r/<!--.*?-->|<\?.*?\?>|\s/s, to_string(rest), "")

        if trailing == "",
          do: {:ok, root},
          else: {:error, "#{path}: malformed XML: content after the root element"}

      {:ok, _state, _rest} ->
        {:error, "#{path}: malformed XML: no root element"}

      {:fatal_error, {_entity, _name, line}, reason, _tags, _state} ->
        {:error, "#{path}:#{line}: malformed XML: #{format_reason(reason)}"}

      {:error, reason} ->
        {:error, "#{path}: malformed XML: #{format_reason(reason)}"}
    end
  catch
    kind, reason ->
      {:error, "#{path}: malformed XML: #{Exception.format_banner(kind, reason)}"}
  end

  defp reverse_children({n, a, children}), do: {n, a, Enum.reverse(children)}

  defp format_reason(reason) when is_list(reason) do
    to_string(reason)
  rescue
    _ -> inspect(reason)
  end

  defp format_reason(reason), do: inspect(reason)

  defp build({"robot", attrs, children}, path) do
    with {:ok, links} <- collect(children, "link", &link(&1, path)),
         {:ok, joints} <- collect(children, "joint", &joint(&1, path)) do
      {:ok,
       %__MODULE__{
         file: path,
         name: Map.get(attrs, "name", ""),
         links: Map.new(links, &{&1.name, &1}),
         joints: Map.new(joints, &{&1.name, &1})
       }}
    end
  end

  defp build({other, _, _}, path),
    do: {:error, "#{path}: not a URDF: the root element is <#{other}>, expected <robot>"}

  defp collect(children, tag, fun) do
    children
    |> Enum.filter(&match?({^tag, _, _}, &1))
    |> Enum.reduce_while({:ok, []}, fn element, {:ok, acc} ->
      case fun.(element) do
        {:ok, item} -> {:cont, {:ok, [item | acc]}}
        error -> {:halt, error}
      end
    end)
    |> case do
      {:ok, items} -> {:ok, Enum.reverse(items)}
      error -> error
    end
  end

  defp link({"link", attrs, children}, path) do
    with {:ok, name} <- name_of(attrs, "link", path),
         where = "link #{inspect(name)}",
         {:ok, visual} <- geometries(children, "visual", where, path),
         {:ok, collision} <- geometries(children, "collision", where, path) do
      {:ok, %{name: name, visual: visual, collision: collision}}
    end
  end

  defp geometries(children, tag, where, path) do
    collect(children, tag, fn {_, _, parts} ->
      with {:ok, origin} <- origin(parts, "#{where} <#{tag}>", path) do
        case Enum.find(parts, &match?({"geometry", _, _}, &1)) do
          {"geometry", _, [shape | _]} -> shape(shape, origin, "#{where} <#{tag}>", path)
          _ -> {:error, "#{path}: #{where} <#{tag}> has no <geometry>"}
        end
      end
    end)
    |> case do
      {:ok, list} -> {:ok, Enum.reject(list, &is_nil/1)}
      error -> error
    end
  end

  defp shape({"cylinder", a, _}, origin, where, path) do
    with {:ok, r} <- number(a, "radius", "#{where} cylinder", path),
         {:ok, l} <- number(a, "length", "#{where} cylinder", path),
         do: {:ok, %{type: :cylinder, radius: r, length: l, origin: origin}}
  end

  defp shape({"box", a, _}, origin, where, path) do
    with {:ok, size} <- vector(a, "size", nil, "#{where} box", path),
         do: {:ok, %{type: :box, size: size, origin: origin}}
  end

  defp shape({"sphere", a, _}, origin, where, path) do
    with {:ok, r} <- number(a, "radius", "#{where} sphere", path),
         do: {:ok, %{type: :sphere, radius: r, origin: origin}}
  end

  defp shape({"mesh", a, _}, origin, where, path) do
    with {:ok, scale} <- vector(a, "scale", {1.0, 1.0, 1.0}, "#{where} mesh", path),
         do:
           {:ok,
            %{type: :mesh, filename: Map.get(a, "filename", ""), scale: scale, origin: origin}}
  end

  # other shapes (e.g. capsule in newer URDF) are ignored
  defp shape(_other, _origin, _where, _path), do: {:ok, nil}

  defp joint({"joint", attrs, children}, path) do
    with {:ok, name} <- name_of(attrs, "joint", path),
         where = "joint #{inspect(name)}",
         {:ok, type} <- joint_type(attrs, where, path),
         {:ok, parent} <- link_ref(children, "parent", where, path),
         {:ok, child} <- link_ref(children, "child", where, path),
         {:ok, origin} <- origin(children, where, path),
         {:ok, axis} <- axis(children, where, path) do
      {:ok, %{name: name, type: type, parent: parent, child: child, origin: origin, axis: axis}}
    end
  end

  defp name_of(attrs, tag, path) do
    case Map.get(attrs, "name") do
      name when is_binary(name) and name != "" -> {:ok, name}
      _ -> {:error, "#{path}: a <#{tag}> without a name"}
    end
  end

  defp joint_type(attrs, where, path) do
    case Map.fetch(@joint_types, Map.get(attrs, "type")) do
      {:ok, type} ->
        {:ok, type}

      :error ->
        {:error,
         "#{path}: #{where}: unknown type #{inspect(Map.get(attrs, "type"))} (expected one of #{Enum.join(Map.keys(@joint_types), ", ")})"}
    end
  end

  defp link_ref(children, tag, where, path) do
    case Enum.find(children, &match?({^tag, _, _}, &1)) do
      {_, %{"link" => link}, _} when link != "" -> {:ok, link}
      _ -> {:error, "#{path}: #{where} has no <#{tag} link=\"...\"/>"}
    end
  end

  defp origin(children, where, path) do
    case Enum.find(children, &match?({"origin", _, _}, &1)) do
      nil ->
        {:ok, @zero_origin}

      {_, a, _} ->
        with {:ok, xyz} <- vector(a, "xyz", {0.0, 0.0, 0.0}, "#{where} origin", path),
             {:ok, rpy} <- vector(a, "rpy", {0.0, 0.0, 0.0}, "#{where} origin", path),
             do: {:ok, {xyz, rpy}}
    end
  end

  defp axis(children, where, path) do
    case Enum.find(children, &match?({"axis", _, _}, &1)) do
      nil -> {:ok, {1.0, 0.0, 0.0}}
      {_, a, _} -> vector(a, "xyz", {1.0, 0.0, 0.0}, "#{where} axis", path)
    end
  end

  defp number(attrs, key, where, path) do
    case parse_numbers(Map.get(attrs, key, "")) do
      [x] -> {:ok, x}
      _ -> {:error, "#{path}: #{where}: #{key}= expected a number, got #{inspect(attrs[key])}"}
    end
  end

  defp vector(attrs, key, default, where, path) do
    case {Map.fetch(attrs, key), default} do
      {:error, default} when default != nil ->
        {:ok, default}

      {found, _} ->
        case parse_numbers(with({:ok, s} <- found, do: s, else: (_ -> ""))) do
          [x, y, z] ->
            {:ok, {x, y, z}}

          _ ->
            {:error,
             "#{path}: #{where}: #{key}= expected 3 numbers, got #{inspect(Map.get(attrs, key))}"}
        end
    end
  end

  defp parse_numbers(text) do
    text
    |> String.split()
    |> Enum.map(fn word ->
      # Float.parse wants a digit before the point: ".5", "-.5"
      word = String.replace(word, ~r/^([+-]?)\./, "\\g{1}0.")

      case Float.parse(word) do
        {x, ""} -> x
        _ -> :error
      end
    end)
    |> then(&if Enum.member?(&1, :error), do: :error, else: &1)
  end

  defp check_tree(urdf) do
    joints = Map.values(urdf.joints)
    parents = joints |> Enum.group_by(& &1.child) |> Enum.find(fn {_, js} -> length(js) > 1 end)

    cond do
      map_size(urdf.links) == 0 ->
        {:error, "#{urdf.file}: the URDF has no <link>"}

      joint = Enum.find(joints, &(not linked?(urdf, &1))) ->
        missing = if Map.has_key?(urdf.links, joint.parent), do: joint.child, else: joint.parent

        {:error,
         "#{urdf.file}: joint #{inspect(joint.name)} names an unknown link #{inspect(missing)}"}

      parents != nil ->
        {child, js} = parents

        {:error,
         "#{urdf.file}: link #{inspect(child)} is the child of several joints: #{js |> Enum.map(& &1.name) |> Enum.sort() |> Enum.map_join(", ", &inspect/1)}"}

      link = Enum.find(Map.keys(urdf.links), &match?({:error, _}, chain(urdf, &1))) ->
        {:error, "#{urdf.file}: the joints form a loop through link #{inspect(link)}"}

      true ->
        {:ok, urdf}
    end
  end

  defp linked?(urdf, joint),
    do: Map.has_key?(urdf.links, joint.parent) and Map.has_key?(urdf.links, joint.child)

  ## Poses

  @doc """
  The pose `{x, y, z, roll, pitch, yaw}` of `link`'s frame in `base`'s
  frame (default `"base_link"`), composing the joints' origins (full 3-D
  rotations) along the tree, whichever of the two is nearer the root.
  """
  @spec pose(t(), String.t(), String.t()) :: {:ok, pose6()} | {:error, String.t()}
  def pose(%__MODULE__{} = urdf, link, base \\ "base_link") do
    with :ok <- known(urdf, link),
         :ok <- known(urdf, base),
         {:ok, {root_l, t_link}} <- from_root(urdf, link),
         {:ok, {root_b, t_base}} <- from_root(urdf, base) do
      if root_l == root_b do
        {r, {x, y, z}} = compose(invert(t_base), t_link)
        {roll, pitch, yaw} = rpy(r)
        {:ok, {x, y, z, roll, pitch, yaw}}
      else
        {:error,
         "#{urdf.file}: links #{inspect(link)} and #{inspect(base)} are not connected by joints"}
      end
    end
  end

  defp known(urdf, link) do
    if Map.has_key?(urdf.links, link),
      do: :ok,
      else:
        {:error,
         "#{urdf.file}: no link named #{inspect(link)} (links: #{urdf.links |> Map.keys() |> Enum.sort() |> Enum.join(", ")})"}
  end

  # The joints from the tree's root down to `link`, root first.
  defp chain(urdf, link) do
    by_child = Map.new(Map.values(urdf.joints), &{&1.child, &1})

    Enum.reduce_while(Stream.cycle([:step]), {link, [], MapSet.new([link])}, fn :step,
                                                                                {at, joints, seen} ->
      case Map.fetch(by_child, at) do
        :error ->
          {:halt, {:ok, {at, joints}}}

        {:ok, joint} ->
          if MapSet.member?(seen, joint.parent),
            do: {:halt, {:error, :loop}},
            else: {:cont, {joint.parent, [joint | joints], MapSet.put(seen, joint.parent)}}
      end
    end)
  end

  defp from_root(urdf, link) do
    case chain(urdf, link) do
      {:ok, {root, joints}} ->
        {:ok, {root, Enum.reduce(joints, identity(), &compose(&2, transform(&1.origin)))}}

      {:error, :loop} ->
        {:error, "#{urdf.file}: the joints form a loop through link #{inspect(link)}"}
    end
  end

  ## Wheels

  @doc """
  The drive wheels of a differential robot: the two `continuous` joints
  whose name contains "wheel" (any case) and whose child link has a
  cylinder (collision geometry preferred, else visual). `separation` is
  the distance between the two wheel frames along the y axis of
  `"base_link"` (of the root link if there is no `base_link`), `radius`
  the cylinders' radius (their mean if they differ).
  """
  @spec wheels(t()) :: {:ok, %{separation: float(), radius: float()}} | {:error, String.t()}
  def wheels(%__MODULE__{} = urdf) do
    wheels =
      for joint <- Map.values(urdf.joints),
          joint.type == :continuous,
          String.contains?(String.downcase(joint.name), "wheel"),
          radius = cylinder_radius(urdf.links[joint.child]),
          do: {joint, radius}

    with {:ok, [{a, ra}, {b, rb}]} <- two(urdf, wheels),
         base = if(Map.has_key?(urdf.links, "base_link"), do: "base_link", else: root(urdf, a)),
         {:ok, {_, ya, _, _, _, _}} <- pose(urdf, a.child, base),
         {:ok, {_, yb, _, _, _, _}} <- pose(urdf, b.child, base) do
      {:ok, %{separation: abs(ya - yb), radius: (ra + rb) / 2}}
    end
  end

  defp two(_urdf, [_, _] = wheels), do: {:ok, Enum.sort_by(wheels, &elem(&1, 0).name)}

  defp two(urdf, wheels),
    do:
      {:error,
       "#{urdf.file}: expected two continuous wheel joints (named *wheel*, their links with a cylinder), found #{length(wheels)}#{if wheels != [], do: ": " <> Enum.map_join(wheels, ", ", &inspect(elem(&1, 0).name)), else: ""}"}

  defp cylinder_radius(link) do
    Enum.find_value(link.collision ++ link.visual, fn
      %{type: :cylinder, radius: r} -> r
      _ -> nil
    end)
  end

  defp root(urdf, joint) do
    {:ok, {root, _}} = chain(urdf, joint.parent)
    root
  end

  ## 3-D transforms: {rotation as rows {{a, b, c}, {d, e, f}, {g, h, i}}, translation}

  defp identity, do: {{{1.0, 0.0, 0.0}, {0.0, 1.0, 0.0}, {0.0, 0.0, 1.0}}, {0.0, 0.0, 0.0}}

  defp transform({xyz, {roll, pitch, yaw}}) do
    {cr, sr} = {:math.cos(roll), :math.sin(roll)}
    {cp, sp} = {:math.cos(pitch), :math.sin(pitch)}
    {cy, sy} = {:math.cos(yaw), :math.sin(yaw)}

    # Rz(yaw) Ry(pitch) Rx(roll)
    r =
      {{cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr},
       {sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr}, {-sp, cp * sr, cp * cr}}

    {r, xyz}
  end

  defp compose({r1, p1}, {r2, p2}), do: {mul(r1, r2), add(apply_r(r1, p2), p1)}

  defp invert({r, p}) do
    rt = transpose(r)
    {x, y, z} = apply_r(rt, p)
    {rt, {-x, -y, -z}}
  end

  defp rpy({{r11, r12, _}, {r21, r22, _}, {r31, r32, r33}}) do
    pitch = :math.atan2(-r31, :math.sqrt(r11 * r11 + r21 * r21))

    if abs(:math.cos(pitch)) < 1.0e-9,
      # gimbal lock: only roll ± yaw is defined, reported as yaw with roll 0
      do: {0.0, pitch, :math.atan2(-r12, r22)},
      else: {:math.atan2(r32, r33), pitch, :math.atan2(r21, r11)}
  end

  defp mul(a, b) do
    bt = transpose(b)

    {row(elem(a, 0), bt), row(elem(a, 1), bt), row(elem(a, 2), bt)}
  end

  defp row(r, {c1, c2, c3}), do: {dot(r, c1), dot(r, c2), dot(r, c3)}

  defp transpose({{a, b, c}, {d, e, f}, {g, h, i}}), do: {{a, d, g}, {b, e, h}, {c, f, i}}

  defp apply_r({r1, r2, r3}, v), do: {dot(r1, v), dot(r2, v), dot(r3, v)}

  defp dot({a, b, c}, {x, y, z}), do: a * x + b * y + c * z

  defp add({a, b, c}, {x, y, z}), do: {a + x, b + y, c + z}
end
