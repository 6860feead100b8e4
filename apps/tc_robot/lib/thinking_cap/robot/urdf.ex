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

  The file is read within bounds (`load/1`): by size, as UTF-8, and by a
  small XML reader of its own (`ThinkingCap.Robot.URDF.XML`) that takes no
  DOCTYPE or entity, bounds depth and element count, and keeps names as
  strings: a URDF cannot fill the atom table, name another file, or take
  unbounded time or memory.
  """

  alias ThinkingCap.Config.Error
  alias ThinkingCap.Robot.URDF.XML

  @max_bytes 4 * 1024 * 1024

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
  Reads and checks a URDF file, within bounds: a file over 4 MB is
  refused unread, one that is not UTF-8 before it is parsed, and the XML
  is read by `ThinkingCap.Robot.URDF.XML` (no DOCTYPE or entities, at most
  64 deep and 100,000 elements, no atoms). Every problem is a
  `ThinkingCap.Config.Error` at its line (column 0: the line of the
  element): malformed XML (the first place only), a root element that is
  not `<robot>`, a link or joint without a name or given twice, a joint of
  an unknown type or without parent or child, a joint naming an unknown
  link, a link with two parents, joints in a loop, numbers that do not
  parse. All of them at once, at most 50 and then how many more.
  """
  @spec load(Path.t()) :: {:ok, t()} | {:error, [Error.t()]}
  def load(path) do
    with {:ok, xml} <- read(path),
         {:ok, root} <- parse(xml, path),
         {:ok, urdf, lines} <- build(root, path),
         {:ok, urdf} <- check_tree(urdf, lines) do
      {:ok, urdf}
    else
      {:error, errors} -> {:error, Error.cap(errors)}
    end
  end

  @doc "One line per error of `load/1`, as `file:line:column: message`."
  @spec format_errors([Error.t()]) :: String.t()
  def format_errors(errors), do: Enum.map_join(errors, "\n", &to_string/1)

  defp read(path) do
    with {:ok, size} <- size(path),
         :ok <- small(path, size),
         {:ok, xml} <- read_file(path),
         :ok <- ThinkingCap.Config.Source.utf8(path, xml) do
      {:ok, xml}
    end
  end

  defp size(path) do
    case File.stat(path) do
      {:ok, %File.Stat{type: :regular, size: size}} -> {:ok, size}
      {:ok, %File.Stat{type: type}} -> fail(path, "the URDF is not a regular file (#{type})")
      {:error, reason} -> fail(path, "cannot read the URDF: #{:file.format_error(reason)}")
    end
  end

  defp small(_path, size) when size <= @max_bytes, do: :ok

  defp small(path, size),
    do: fail(path, "#{size} bytes: a URDF is limited to #{@max_bytes} bytes")

  defp read_file(path) do
    case File.read(path) do
      {:ok, xml} -> {:ok, xml}
      {:error, reason} -> fail(path, "cannot read the URDF: #{:file.format_error(reason)}")
    end
  end

  defp fail(path, message), do: {:error, [Error.new(path, {0, 0}, message)]}

  defp parse(xml, path) do
    case XML.parse(xml) do
      {:ok, root} ->
        {:ok, root}

      {:error, line, message} ->
        {:error, [Error.new(path, {line, 0}, "malformed XML: #{message}")]}
    end
  end

  # Every <link> and <joint> is read, each problem an error at its line.
  defp build({"robot", attrs, children}, path) do
    {items, errors} =
      Enum.reduce(children, {[], []}, fn
        {"link", a, _} = element, acc -> item(acc, :link, a.line, link(element), path)
        {"joint", a, _} = element, acc -> item(acc, :joint, a.line, joint(element), path)
        _other, acc -> acc
      end)

    {links, joints, lines, errors} =
      items
      |> Enum.reverse()
      |> Enum.reduce({%{}, %{}, %{}, errors}, fn {kind, line, item},
                                                 {links, joints, lines, errors} ->
        case Map.fetch(lines, {kind, item.name}) do
          {:ok, first} ->
            message = "#{kind} #{inspect(item.name)} is given twice (first at line #{first})"
            {links, joints, lines, [Error.new(path, {line, 0}, message) | errors]}

          :error ->
            lines = Map.put(lines, {kind, item.name}, line)

            if kind == :link,
              do: {Map.put(links, item.name, item), joints, lines, errors},
              else: {links, Map.put(joints, item.name, item), lines, errors}
        end
      end)

    case errors do
      [] ->
        {:ok,
         %__MODULE__{file: path, name: Map.get(attrs, "name", ""), links: links, joints: joints},
         lines}

      _ ->
        {:error, errors |> Enum.reverse() |> Enum.sort_by(& &1.line)}
    end
  end

  defp build({other, attrs, _}, path),
    do:
      {:error,
       [
         Error.new(
           path,
           {attrs.line, 0},
           "not a URDF: the root element is <#{other}>, expected <robot>"
         )
       ]}

  defp item({items, errors}, kind, line, {:ok, item}, _path),
    do: {[{kind, line, item} | items], errors}

  defp item({items, errors}, _kind, line, {:error, message}, path),
    do: {items, [Error.new(path, {line, 0}, message) | errors]}

  # the first error of each element, or its items
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

  defp link({"link", attrs, children}) do
    with {:ok, name} <- name_of(attrs, "link"),
         where = "link #{inspect(name)}",
         {:ok, visual} <- geometries(children, "visual", where),
         {:ok, collision} <- geometries(children, "collision", where) do
      {:ok, %{name: name, visual: visual, collision: collision}}
    end
  end

  defp geometries(children, tag, where) do
    collect(children, tag, fn {_, a, parts} ->
      with {:ok, origin} <- origin(parts, "#{where} <#{tag}>") do
        case Enum.find(parts, &match?({"geometry", _, _}, &1)) do
          {"geometry", _, [shape | _]} -> shape(shape, origin, "#{where} <#{tag}>")
          _ -> {:error, "#{where} <#{tag}> (line #{a.line}) has no <geometry>"}
        end
      end
    end)
    |> case do
      {:ok, list} -> {:ok, Enum.reject(list, &is_nil/1)}
      error -> error
    end
  end

  defp shape({"cylinder", a, _}, origin, where) do
    with {:ok, r} <- number(a, "radius", "#{where} cylinder"),
         {:ok, l} <- number(a, "length", "#{where} cylinder"),
         do: {:ok, %{type: :cylinder, radius: r, length: l, origin: origin}}
  end

  defp shape({"box", a, _}, origin, where) do
    with {:ok, size} <- vector(a, "size", nil, "#{where} box"),
         do: {:ok, %{type: :box, size: size, origin: origin}}
  end

  defp shape({"sphere", a, _}, origin, where) do
    with {:ok, r} <- number(a, "radius", "#{where} sphere"),
         do: {:ok, %{type: :sphere, radius: r, origin: origin}}
  end

  defp shape({"mesh", a, _}, origin, where) do
    with {:ok, scale} <- vector(a, "scale", {1.0, 1.0, 1.0}, "#{where} mesh"),
         do:
           {:ok,
            %{type: :mesh, filename: Map.get(a, "filename", ""), scale: scale, origin: origin}}
  end

  # other shapes (e.g. capsule in newer URDF) are ignored
  defp shape(_other, _origin, _where), do: {:ok, nil}

  defp joint({"joint", attrs, children}) do
    with {:ok, name} <- name_of(attrs, "joint"),
         where = "joint #{inspect(name)}",
         {:ok, type} <- joint_type(attrs, where),
         {:ok, parent} <- link_ref(children, "parent", where),
         {:ok, child} <- link_ref(children, "child", where),
         {:ok, origin} <- origin(children, where),
         {:ok, axis} <- axis(children, where) do
      {:ok, %{name: name, type: type, parent: parent, child: child, origin: origin, axis: axis}}
    end
  end

  defp name_of(attrs, tag) do
    case Map.get(attrs, "name") do
      name when is_binary(name) and name != "" -> {:ok, name}
      _ -> {:error, "a <#{tag}> without a name"}
    end
  end

  defp joint_type(attrs, where) do
    case Map.fetch(@joint_types, Map.get(attrs, "type")) do
      {:ok, type} ->
        {:ok, type}

      :error ->
        {:error,
         "#{where}: unknown type #{inspect(Map.get(attrs, "type"))} (expected one of #{Enum.join(Map.keys(@joint_types), ", ")})"}
    end
  end

  defp link_ref(children, tag, where) do
    case Enum.find(children, &match?({^tag, _, _}, &1)) do
      {_, %{"link" => link}, _} when link != "" -> {:ok, link}
      _ -> {:error, "#{where} has no <#{tag} link=\"...\"/>"}
    end
  end

  defp origin(children, where) do
    case Enum.find(children, &match?({"origin", _, _}, &1)) do
      nil ->
        {:ok, @zero_origin}

      {_, a, _} ->
        with {:ok, xyz} <- vector(a, "xyz", {0.0, 0.0, 0.0}, "#{where} origin"),
             {:ok, rpy} <- vector(a, "rpy", {0.0, 0.0, 0.0}, "#{where} origin"),
             do: {:ok, {xyz, rpy}}
    end
  end

  defp axis(children, where) do
    case Enum.find(children, &match?({"axis", _, _}, &1)) do
      nil -> {:ok, {1.0, 0.0, 0.0}}
      {_, a, _} -> vector(a, "xyz", {1.0, 0.0, 0.0}, "#{where} axis")
    end
  end

  defp number(attrs, key, where) do
    case parse_numbers(Map.get(attrs, key, "")) do
      [x] -> {:ok, x}
      _ -> {:error, "#{where}: #{key}= expected a number, got #{shown(attrs[key])}"}
    end
  end

  defp vector(attrs, key, default, where) do
    case {Map.fetch(attrs, key), default} do
      {:error, default} when default != nil ->
        {:ok, default}

      {found, _} ->
        case parse_numbers(with({:ok, s} <- found, do: s, else: (_ -> ""))) do
          [x, y, z] ->
            {:ok, {x, y, z}}

          _ ->
            {:error, "#{where}: #{key}= expected 3 numbers, got #{shown(Map.get(attrs, key))}"}
        end
    end
  end

  # a value in a message: at most 80 characters of it
  defp shown(value) when is_binary(value) and byte_size(value) > 80,
    do: inspect(String.slice(value, 0, 80) <> "...")

  defp shown(value), do: inspect(value)

  # finite numbers only (Float.parse refuses what overflows), at most 64 bytes each
  defp parse_numbers(text) do
    text
    |> String.split()
    |> Enum.reduce_while([], fn word, acc ->
      # Float.parse wants a digit before the point: ".5", "-.5"
      word = String.replace(word, ~r/^([+-]?)\./, "\\g{1}0.")

      case byte_size(word) <= 64 and Float.parse(word) do
        {x, ""} when length(acc) < 3 -> {:cont, [x | acc]}
        _ -> {:halt, :error}
      end
    end)
    |> then(&if &1 == :error, do: :error, else: Enum.reverse(&1))
  end

  defp check_tree(urdf, lines) do
    joints = urdf.joints |> Map.values() |> Enum.sort_by(&lines[{:joint, &1.name}])
    at = fn kind, name -> {Map.get(lines, {kind, name}, 0), 0} end

    errors =
      for joint <- joints, not linked?(urdf, joint) do
        missing = if Map.has_key?(urdf.links, joint.parent), do: joint.child, else: joint.parent

        Error.new(
          urdf.file,
          at.(:joint, joint.name),
          "joint #{inspect(joint.name)} names an unknown link #{inspect(missing)}"
        )
      end ++
        for {child, [_, _ | _] = js} <- Enum.group_by(joints, & &1.child) do
          Error.new(
            urdf.file,
            at.(:link, child),
            "link #{inspect(child)} is the child of several joints: #{js |> Enum.map(& &1.name) |> Enum.sort() |> Enum.map_join(", ", &inspect/1)}"
          )
        end

    loop = errors == [] && loop_link(urdf)

    cond do
      map_size(urdf.links) == 0 ->
        {:error, [Error.new(urdf.file, {0, 0}, "the URDF has no <link>")]}

      errors != [] ->
        {:error, Enum.sort_by(errors, & &1.line)}

      loop ->
        {:error,
         [
           Error.new(
             urdf.file,
             at.(:link, loop),
             "the joints form a loop through link #{inspect(loop)}"
           )
         ]}

      true ->
        {:ok, urdf}
    end
  end

  # A link on a loop of joints, or nil. Each link is walked up to the root
  # once at most (a walk stops at a link known to reach the root): linear
  # in the links, where a chain per link would be quadratic on a long arm.
  defp loop_link(urdf) do
    parent_of = Map.new(Map.values(urdf.joints), &{&1.child, &1.parent})

    urdf.links
    |> Map.keys()
    |> Enum.sort()
    |> Enum.reduce_while(MapSet.new(), fn link, rooted ->
      case walk_up(link, parent_of, rooted, [], MapSet.new()) do
        {:ok, rooted} -> {:cont, rooted}
        {:loop, at} -> {:halt, {:loop, at}}
      end
    end)
    |> case do
      {:loop, at} -> at
      _rooted -> nil
    end
  end

  defp walk_up(link, parent_of, rooted, path, on_path) do
    cond do
      MapSet.member?(rooted, link) ->
        {:ok, Enum.reduce(path, rooted, &MapSet.put(&2, &1))}

      MapSet.member?(on_path, link) ->
        {:loop, link}

      true ->
        case Map.fetch(parent_of, link) do
          {:ok, parent} ->
            walk_up(parent, parent_of, rooted, [link | path], MapSet.put(on_path, link))

          :error ->
            {:ok, Enum.reduce([link | path], rooted, &MapSet.put(&2, &1))}
        end
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
